"""A pose saved before a restart of the infer stage, and the odometry saved with it: the restarted stage carries
the pose across the restart with the odometry that arrives after it (the MCU kept counting), instead of growing
its spread by `motion_sigma_mps` for every second the restart took; a saved time is trusted only while the
frames' clock agrees with the wall clock about its age."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from courtloc.common.messages import Header, Odometry
from courtloc.localizer import acquire
from courtloc.localizer.config import AcquireConfig
from courtloc.localizer.odometry_fusion import FusionConfig, OdometryFusion
from courtloc.localizer.tracking import Tracker
from courtloc.services.infer.resume import ResumeFile, SavedPose

SPEED = 1.5  # m/s along the odometry frame's x, which is the court's +y here (the robot faces +y)
POSE = np.array([2.0, -1.0, math.pi / 2])


def _odometry(t: float, seq: int, epoch: int = 0) -> Odometry:
    header = Header(robot_id="robot1", seq=seq, capture_mono_ns=int(round(t * 1e9)), capture_wall_ns=0, valid=True)
    return Odometry(header=header, source="test", source_seq=seq, source_time_ns=int(round(t * 1e9)),
                    received_mono_ns=int(round(t * 1e9)), window_s=0.01, wheels_valid=True, gyro_valid=True,
                    epoch=epoch, odom_x_m=SPEED * t, vx_m_s=SPEED)


def _feed(fusion: OdometryFusion, t0: float, t1: float, epoch: int = 0) -> None:
    for i in range(int(round(t0 * 100)), int(round(t1 * 100)) + 1):
        assert fusion.offer(_odometry(i * 0.01, seq=i, epoch=epoch), now_s=i * 0.01 + 0.005)


def _saved_and_reloaded(tmp_path: Path) -> tuple[OdometryFusion, acquire.Prior]:
    """The stage before the restart: tracking at 1.0 s, odometry up to 1.02 s, the pose saved; then the file
    read back as the restarted stage reads it."""
    before = OdometryFusion(FusionConfig(enabled=True))
    _feed(before, 0.0, 1.02)
    prior = acquire.Prior("track", pose=POSE, std_m=0.02, yaw_std_rad=math.radians(0.5), t=1.0)
    resume = ResumeFile(tmp_path / "last-pose.json", "robot1")
    resume.offer(prior, "robocon2025", wall_ns=10**18, odometry=before.snapshot(1.0))
    # Read as written (load() would also check the age against today's wall clock).
    loaded = SavedPose.model_validate_json(resume.path.read_text())
    assert loaded.t_s == 1.0 and 1 <= len(loaded.odometry) <= 16
    after = OdometryFusion(FusionConfig(enabled=True))
    samples, last = loaded.odometry_snapshot()
    assert last is not None and after.resume(samples, last)
    return after, loaded.prior()


@pytest.mark.parametrize("restart_s", [1.3, 4.0])
def test_a_saved_pose_is_carried_across_the_restart_by_the_odometry_after_it(tmp_path: Path, restart_s: float) -> None:
    """A restart of 1.3 s, and one longer than the buffer keeps odometry (buffer_s 3 s): the snapshot stays."""
    after, prior = _saved_and_reloaded(tmp_path)
    assert restart_s < after.config.resume_hold_s
    first = 1.0 + restart_s  # the robot drove on at 1.5 m/s all along
    _feed(after, first, first + 0.7)
    now = first + 0.7
    carried = after.carry_prior(prior)
    pose, std_m, yaw_std = carried.spread_at(now, AcquireConfig())
    # At 1.5 m/s facing +y since the pose's time (1e-6: interpolation of exact dead reckoning).
    driven = SPEED * (now - 1.0)
    assert pose[0] == pytest.approx(POSE[0], abs=1e-6) and pose[1] == pytest.approx(POSE[1] + driven, abs=1e-6)
    # Its spread is the odometry's over the distance driven (wheel noise, scale uncertainty, the heading's spread
    # over the lever arm; their sum bounds their root-sum-square), not 0.5 m per second of the restart.
    cfg = FusionConfig()
    bound = 0.02 + (cfg.wheel_noise_per_m + cfg.scale_sigma) * driven + driven * math.radians(0.5) + 0.01
    yaw_bound = math.radians(0.5) + cfg.gyro_bias_sigma_rad_s * (now - 1.0) + cfg.yaw_noise_floor_rad  # gyro bias
    assert std_m < bound and yaw_std is not None and yaw_std < yaw_bound
    # Without the snapshot the new stage's odometry starts after the pose: the prior stays behind and widens.
    fresh = OdometryFusion(FusionConfig(enabled=True))
    _feed(fresh, first, now)
    pose, std_m, _ = fresh.carry_prior(prior).spread_at(now, AcquireConfig())
    assert pose[1] == pytest.approx(POSE[1])
    assert std_m == pytest.approx(0.02 + AcquireConfig().motion_sigma_mps * (now - 1.0))
    assert after.counts["resumed"] == 1
    # Once the hold is over the buffer keeps buffer_s again.
    _feed(after, now + 0.01, 1.02 + cfg.resume_hold_s + 0.5)
    assert after.buffer.samples[-1].t - after.buffer.samples[0].t <= cfg.buffer_s


def test_a_snapshot_is_refused_by_a_fusion_that_has_odometry_or_across_epochs(tmp_path: Path) -> None:
    before = OdometryFusion(FusionConfig(enabled=True))
    _feed(before, 0.0, 0.5)
    samples, last = before.snapshot(0.45)
    assert last is not None and samples[0].t <= 0.45 <= samples[-1].t
    assert before.snapshot(-1.0) == ([], None)  # the buffer does not reach back that far
    busy = OdometryFusion(FusionConfig(enabled=True))
    _feed(busy, 0.0, 0.1)
    assert not busy.resume(samples, last)
    other_epoch = OdometryFusion(FusionConfig(enabled=True))
    assert not other_epoch.resume(samples, type(last)(**{**last.__dict__, "epoch": last.epoch + 1}))
    # A new epoch after the restart (the MCU reset its count): nothing before it can be differenced with it.
    after = OdometryFusion(FusionConfig(enabled=True))
    assert after.resume(samples, last)
    _feed(after, 1.5, 2.0, epoch=1)
    prior = acquire.Prior("track", pose=POSE, std_m=0.02, yaw_std_rad=0.01, t=0.45)
    assert after.carry_prior(prior).spread_at(2.0, AcquireConfig())[0][1] == pytest.approx(POSE[1])


@pytest.mark.parametrize("frame_t, wall_age_s, kept", [(3.0, 2.0, True), (3.0, 2.4, True), (3.0, 2.6, False),
                                                       (0.5, 2.0, False)])
def test_a_saved_time_is_kept_only_while_the_frames_clock_agrees_with_the_wall_clock(frame_t: float, wall_age_s: float,
                                                                                      kept: bool) -> None:
    """Saved at t = 1.0 s on the frames' clock. A frame at 3.0 s whose wall clock says 2.0 s later keeps it (the
    odometry can carry it from then); one the wall clock puts 2.6 s later, or a frame clock that restarted
    (0.5 s: a reboot), drops it, and the wall-clock age spreads the prior instead."""
    tracker = Tracker()
    saved_wall = 10**18
    tracker.set_prior(acquire.Prior("track", pose=POSE, std_m=0.02, yaw_std_rad=0.01, t=1.0), wall_ns=saved_wall)
    state = tracker.state_for(saved_wall + int(wall_age_s * 1e9), frame_t)
    assert isinstance(state, acquire.Acquiring) and state.prior is not None
    assert (state.prior.t == 1.0) is kept
    assert state.prior.age_s == pytest.approx(wall_age_s)
    if not kept:
        assert state.prior.at(frame_t).t == pytest.approx(frame_t - wall_age_s)
