"""The no-twist increments of a topple measured about the vertical of frame 0 (fall.standing_axis)."""
import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.fall import standing_axis, twist_steps
from service.transforms import so3_exp


def _topple(n=30):
    """Poses (N,4,4) of a body standing at frame 0 (axis ẑ in O) tipping by 90° about the horizontal x axis of W
    through its base edge, without turning about its own axis."""
    X = np.tile(np.eye(4), (n, 1, 1))
    for i, t in enumerate(np.linspace(0, np.pi / 2, n)):
        X[i, :3, :3] = so3_exp(np.array([t, 0.0, 0.0]))
        X[i, :3, 3] = [0.0, 0.03 * np.sin(t), 0.1 * np.cos(t)]
    return X


def test_twist_about_the_vertical_of_frame_0():
    X = _topple()
    off = so3_exp(np.array([0.0, np.radians(6.0), 0.0])) @ np.array([0.0, 0.0, 1.0])  # found axis 6° off
    leak = np.degrees(np.sum(twist_steps(X, off)))
    assert abs(leak) > 8.0  # about 90° sin 6° = 9.4° of false twist
    a = standing_axis(off)
    assert np.allclose(a, [0, 0, 1])
    assert abs(np.degrees(np.sum(twist_steps(X, a)))) < 1e-6
    assert np.allclose(standing_axis(-off), [0, 0, -1])  # the found axis' sign kept


def test_not_standing_keeps_the_found_axis():
    a = np.array([1.0, 0.2, 0.3])
    assert np.allclose(standing_axis(a), a / np.linalg.norm(a))


def test_setting_refused():
    with pytest.raises(ValueError, match="spin_fall_axis"):
        TrackingConfig(spin_fall_axis="up")
