from courtloc.localizer.tracking import Tracker


def test_valid_and_trackable_poses_are_kept() -> None:
    tracker = Tracker(max_lost_frames=2)
    tracker.update(1.0, 2.0, 0.5, valid=True, trackable=True)
    assert tracker.previous == (1.0, 2.0, 0.5)
    tracker.update(1.1, 2.0, 0.5, valid=False, trackable=True)  # degenerate view: ride through it
    assert tracker.previous == (1.1, 2.0, 0.5)


def test_lost_track_is_dropped_after_the_limit() -> None:
    tracker = Tracker(max_lost_frames=2)
    tracker.update(1.0, 2.0, 0.5, valid=True, trackable=True)
    tracker.update(9.0, 9.0, 0.0, valid=False, trackable=False)
    tracker.update(9.0, 9.0, 0.0, valid=False, trackable=False)
    assert tracker.previous == (1.0, 2.0, 0.5), "a couple of bad frames keep the last good start"
    tracker.update(9.0, 9.0, 0.0, valid=False, trackable=False)
    assert tracker.previous is None, "then the model searches the court again"
    tracker.update(3.0, 1.0, None, valid=True, trackable=True)
    assert tracker.previous is None, "a pose without yaw cannot seed tracking"


def test_reset_drops_the_models_motion_state_too() -> None:
    tracker = Tracker()
    tracker.update(1.0, 2.0, 0.5, valid=True, trackable=True)
    tracker.motion = object()  # opaque: whatever the model's `track` returned
    tracker.reset()
    assert tracker.previous is None and tracker.motion is None
