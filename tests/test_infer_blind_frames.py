"""A frame without hits still steps a geometric model's tracker: the track coasts and is lost after its
lost-frame limit, as in `courtloc eval`, instead of being found lost only by the time gap at the next seen
frame (then its prior was as old as the blind spell: after a 2 s blackout on the seed twin it decided
nothing for 25 s, where the replay of the same frames recovered in 0.2 s)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from courtloc.common.bus import ZenohConfig
from courtloc.common.messages import Edges, Header
from courtloc.localizer import acquire, motion
from courtloc.localizer.tracking import Tracker
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.service import InferService


def test_a_blind_frame_coasts_the_track_and_enough_of_them_lose_it(tmp_path: Path) -> None:
    service = InferService("robot1", ZenohConfig(), InferConfig(store=tmp_path / "store"))
    model = service._load_active()  # the bundled package of the built-in deployment's court
    motion_cfg = model.predictor.localizer.config.motion
    tracker = Tracker()
    tracker.motion = motion.start(np.array([1.0, 2.0, 0.5]), None, 0.0, motion_cfg)
    no_hits = np.zeros((0, 4), np.int16)
    for k in range(1, motion_cfg.max_lost_frames + 2):
        header = Header.now("robot1", k, "preprocess")
        header.capture_mono_ns = int(k / 30 * 1e9)  # frames 1/30 s apart on the tracker's clock
        edges = Edges(header=header, width=640, height=480, crop_top=0, n_hits=0, hits=b"")
        pose = service.make_pose(model, edges, no_hits, fresh=True, tracker=tracker)
        assert not pose.header.valid
        if k == 1:
            assert pose.reason == "no_hits" and isinstance(tracker.motion, motion.MotionState)
            assert tracker.motion.lost == 1  # coasted one frame
    # After the lost-frame limit the track became an acquisition whose prior is the coasted track.
    assert isinstance(tracker.motion, acquire.Acquiring)
    assert tracker.motion.prior is not None and tracker.motion.prior.source == "track"
