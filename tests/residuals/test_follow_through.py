"""Restitution's blocks without the follow-throughs (``ResidualConfig.restitution_follow_frames``): a launch block
whose robot contact lasts more than N frames from the onset is not one of restitution's blocks (the sphere pushes
the box on, so its speed, not the bounce, sets the launch); a clean strike's block stays, and the other effects'
blocks do not change. On by default (N = 2); None turns it off."""

import dataclasses

import numpy as np
import pytest

from service.residuals.effects import REGISTRY
from service.residuals.loop import effect_mask, follow_frames, make_segments
from service.residuals.modes import FREE, REST, ROBOT, SLIDING
from service.residuals.types import ObservedTrajectory, ResidualConfig, ResidualInputs, RobotPath
from service.transforms import make_X
from tests.residuals.lab import cube_model

H = 1.0 / 30.0


def test_follow_frames_counts_the_contact_from_the_onset():
    mode = np.array([ROBOT, REST, ROBOT, ROBOT, ROBOT, ROBOT, SLIDING, ROBOT, ROBOT])
    tracked = np.ones(len(mode), bool)
    assert follow_frames(mode, tracked, 3) == 5  # frames 3, 4, 5 and the re-touch 7, 8; not those before the onset
    assert follow_frames(mode, tracked, 0) == 7
    assert follow_frames(np.full(6, REST), np.ones(6, bool), 2) == 0
    tracked[4] = False
    assert follow_frames(mode, tracked, 3) == 4  # untracked frames do not count


def _session(contacts: tuple[int, ...]):
    """A box at rest struck every 30 frames (30 Hz), launched at 0.6 m/s and sliding 6 frames to rest; the k-th
    strike's robot contact lasts ``contacts[k]`` frames from the onset (modes given, as the classifier's)."""
    n = 30 * len(contacts) + 20
    x = np.zeros(n)
    mode = np.full(n, REST)
    for k, c in enumerate(contacts):
        a = 10 + 30 * k  # onset: first frame of motion
        speed = np.array([0.6, 0.5, 0.4, 0.3, 0.2, 0.1])
        x[a:] = x[a - 1] + 0.0
        for i, s in enumerate(speed):
            x[a + i:] += s * H
        mode[a:a + 6] = SLIDING
        mode[a - 2:a - 2 + c] = ROBOT  # c frames from the detected onset (two frames before the first move) on
    t = np.arange(n) * H
    X = np.array([make_X(np.eye(3), np.array([xi, 0.0, 0.0525])) for xi in x])
    tr = np.linspace(0, t[-1], 8 * n)
    p = np.stack([np.interp(tr, t, x) - 0.08, np.zeros_like(tr), np.full_like(tr, 0.05)], 1)
    robot = RobotPath(t=tr, p_WE=p, cmd_WE=p, radius=0.02)
    inputs = ResidualInputs(cube_model(), (ObservedTrajectory(t=t, X_WO=X),), 0.0, robot=(robot,))
    return inputs, [mode]


@pytest.mark.parametrize("n_follow", [2, 3])
def test_follow_through_blocks_leave_restitution_only(n_follow):
    inputs, modes = _session((1, 2, 3, 6, 2, 10))
    base = ResidualConfig(restitution_follow_frames=None)  # off
    off = make_segments(inputs, modes, base)
    on = make_segments(inputs, modes, dataclasses.replace(base, restitution_follow_frames=n_follow))
    assert [(s.start, s.stop) for s in off] == [(s.start, s.stop) for s in on]  # the blocks do not change
    # the detected onset is two frames before the first move (the speed exceeds launch_speed within 3 frames)
    launch = {10 + 30 * k - 2 - base.launch_lead: c for k, c in enumerate((1, 2, 3, 6, 2, 10))}
    assert set(launch) <= {s.start for s in on}
    rest, fric = REGISTRY["restitution"], REGISTRY["friction_table"]
    for a, b in zip(off, on):
        assert not a.follow_through
        assert np.array_equal(effect_mask(a, fric), effect_mask(b, fric))
        if b.start in launch and launch[b.start] > n_follow:
            assert b.follow_through and not effect_mask(b, rest).any() and effect_mask(a, rest).sum() >= 3
        else:
            assert not b.follow_through and np.array_equal(effect_mask(a, rest), effect_mask(b, rest))


def test_config_refuses_a_bad_follow_frames():
    for v in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="restitution_follow_frames"):
            ResidualConfig(restitution_follow_frames=v)
    assert ResidualConfig(restitution_follow_frames=2).restitution_follow_frames == 2


def test_on_by_default_at_two_frames():
    """The default (on since "Restitution without the follow-throughs on fresh strike sessions"): N = 2, and a
    default config leaves out the blocks with contacts of 3, 6 and 10 frames, keeping those of 1 and 2."""
    assert ResidualConfig().restitution_follow_frames == 2
    inputs, modes = _session((1, 2, 3, 6, 2, 10))
    segs = make_segments(inputs, modes, ResidualConfig())
    launch = {10 + 30 * k - 2 - ResidualConfig().launch_lead: c for k, c in enumerate((1, 2, 3, 6, 2, 10))}
    assert {s.start for s in segs if s.follow_through} == {a for a, c in launch.items() if c > 2}
