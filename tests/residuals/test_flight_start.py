"""Start states of blocks that start in free flight (docs/residuals.md §1, "Start state of a block"):
``init_fit_frames_flight`` fits the model-free quadratic on the flight stretch around the start instead of the
centred 9 frames (the blocks do not change, and the window never leaves the flight)."""

import dataclasses

import numpy as np

from service.residuals.loop import flight_window, make_segments
from service.residuals.modes import FREE, REST
from service.residuals.types import ObservedTrajectory, ResidualConfig, ResidualInputs
from service.transforms import make_X, so3_exp
from tests.residuals.lab import cube_model
from tests.residuals.test_parts import _free_flight

H = 1.0 / 148.0
G = np.array([0.0, 0.0, -9.81])
NOISE = 1.5e-4  # m; the rotation noise is NOISE / 5.24 cm rad, as the synthetic tosses


def _toss(rng, n=40, flight=20):
    """A noisy toss: ``flight`` frames of free flight (spin about a fixed axis), then frames at rest (modes given)."""
    v0, w0 = rng.normal(0, 0.5, 3), rng.normal(0, 3.0, 3)
    X = _free_flight(v0, w0, G, H, n, R0=so3_exp(rng.normal(size=3)), p0=np.array([0.0, 0.0, 1.0]))
    true_v = v0 + np.arange(n)[:, None] * G * H  # backward-difference velocity at each frame
    Xn = X.copy()
    Xn[:, :3, 3] += rng.normal(0, NOISE, (n, 3))
    Xn[:, :3, :3] = so3_exp(rng.normal(0, NOISE / 0.0524, (n, 3))) @ Xn[:, :3, :3]
    mode = np.full(n, REST)
    mode[:flight] = FREE
    return ObservedTrajectory(t=np.arange(n) * H, X_WO=Xn), mode, true_v, w0


def test_flight_window_stays_in_the_flight_and_within_half_either_side():
    mode = np.array([FREE] * 12 + [REST] * 5 + [FREE] * 6)
    tracked = np.ones(len(mode), bool)
    assert flight_window(mode, tracked, 4, 41) == (0, 12)  # the whole stretch: 4 frames before, 7 after
    assert flight_window(mode, tracked, 6, 5) == (4, 9)  # at most 5 // 2 frames either side
    assert flight_window(mode, tracked, 13, 41) == (13, 13)  # not a flight frame: empty
    assert flight_window(mode, tracked, 19, 41) == (17, 23)  # the second flight only
    tracked[2] = False
    assert flight_window(mode, tracked, 4, 41) == (3, 12)  # an untracked frame ends the stretch


def test_flight_stretch_fit_lowers_the_start_state_error_and_keeps_the_blocks():
    rng = np.random.default_rng(0)
    tosses = [_toss(rng) for _ in range(40)]
    inputs = ResidualInputs(cube_model(), tuple(tr for tr, *_ in tosses), 0.0)
    modes = [m for _, m, *_ in tosses]
    base = ResidualConfig(sim_substep_s=H)  # the data are semi-implicit Euler at one step per frame
    err = {}
    for k in (0, 41):
        segs = make_segments(inputs, modes, dataclasses.replace(base, init_fit_frames_flight=k))
        err[k] = segs
    assert [(s.traj, s.start, s.stop) for s in err[0]] == [(s.traj, s.start, s.stop) for s in err[41]]
    first = {k: [s for s in err[k] if s.start == 4] for k in err}  # the first block of each toss, in flight
    assert len(first[0]) == 40

    def rms(segs):
        dv = [np.linalg.norm(s.v0 - tosses[s.traj][2][s.start]) for s in segs]
        dw = [np.linalg.norm(s.w0 - tosses[s.traj][3]) for s in segs]
        return np.sqrt(np.mean(np.square(dv))), np.sqrt(np.mean(np.square(dw)))

    (v9, w9), (v41, w41) = rms(first[0]), rms(first[41])
    # window [0, 20) about frame 4 against [0, 9): the quadratic's slope error there is 0.71x (theory)
    assert v41 < 0.85 * v9 and w41 < 0.85 * w9
    # blocks starting at rest are untouched
    rest0 = [s for s in err[0] if s.mode[0] == REST]
    rest41 = [s for s in err[41] if s.mode[0] == REST]
    assert rest0 and all(np.array_equal(a.v0, b.v0) and np.array_equal(a.X0, b.X0) for a, b in zip(rest0, rest41))
