"""Start states of blocks that start in free flight (docs/residuals.md §1, "Start state of a block"):
``init_fit_frames_flight`` fits the model-free quadratic on the flight stretch around the start instead of the
centred 9 frames (the blocks do not change, and the window never leaves the flight); ``flight_start_model`` fits it
per model with that model's flight dynamics (off: it lowers the error of the model without the effect on the frames it
was fitted on, §7)."""

import dataclasses

import numpy as np

from service.residuals.effects import apply_effects
from service.residuals.loop import flight_start_state, flight_window, make_segments, start_state
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


def test_flight_start_state_is_exact_with_the_right_model_and_the_quadratic_without_it():
    """Noise-free semi-implicit flight: the per-model fit recovers the start state for the model that made the data
    (a gravity scale, here) on an off-centre window, and the model-free quadratic does on the centred one."""
    g = 0.95 * G
    v0, w0 = np.array([0.4, -0.1, 0.3]), np.array([1.0, -2.0, 0.5])
    X = _free_flight(v0, w0, g, H, 20, R0=so3_exp(np.array([0.3, 0.1, -0.2])), p0=np.array([0.0, 0.0, 1.0]))
    t = np.arange(20) * H
    model, eff = apply_effects(cube_model(), {"gravity_scale": (0.95,)})
    X4, v4, w4 = flight_start_state(t, X, 4, H, model, eff)
    assert np.allclose(v4, v0 + 4 * g * H, atol=1e-9) and np.allclose(w4, w0, atol=1e-6)
    assert np.allclose(X4, X[4], atol=1e-9)
    Xq, vq, wq = start_state(t[:9], X[:9], 4, H)
    assert np.allclose(vq, v4, atol=1e-9)
    # with the nominal gravity the off-centre fit is biased: the model's own dynamics enter the start state
    _, v_nom, _ = flight_start_state(t, X, 4, H, cube_model(), {})
    assert np.linalg.norm(v_nom - v4) > 1e-3


def test_evaluator_fits_the_flight_start_again_only_when_its_inputs_change(monkeypatch):
    """``Evaluator.start`` hands each rollout ``flight_start_state`` of its (model, effects), bit for bit, but fits it
    again only when what the fit reads (``flight_params``: gravity, damping, CoM, inertia) changed since the block's
    previous rollout: a friction leaves it as it was, a gravity scale or another CoM does not."""
    import service.residuals.loop as loop

    rng = np.random.default_rng(3)
    tosses = [_toss(rng) for _ in range(3)]
    inputs = ResidualInputs(cube_model(), tuple(tr for tr, *_ in tosses), 0.0)
    cfg = ResidualConfig(sim_substep_s=H, flight_start_model=True, init_fit_frames_flight=41)
    segs = make_segments(inputs, [m for _, m, *_ in tosses], cfg)
    flight = [s for s in segs if s.fit is not None]
    assert flight and any(s.fit is None for s in segs)
    fits = []
    real = loop._flight_fit
    monkeypatch.setattr(loop, "_flight_fit", lambda *a: fits.append(a) or real(*a))
    ev = loop.Evaluator(None, 0.0, 0.05)
    model = cube_model()
    shifted = dataclasses.replace(model, com_O=np.array([0.002, 0.0, -0.001]))
    steps = [(model, {}, True), (model, {"friction_object_table": 0.3}, False), (model, {}, False),
             (model, {"gravity_scale": 0.95}, True), (model, {"gravity_scale": 0.95, "restitution": 0.4}, False),
             (model, {"linear_damping": 0.2}, True), (shifted, {"linear_damping": 0.2}, True), (model, {}, True)]
    for m, eff, fitted in steps:
        for s in flight:
            n = len(fits)
            got = ev.start(m, eff, s)
            assert len(fits) == n + fitted, (eff, fitted)
            want = flight_start_state(*s.fit, m, eff)
            assert all(np.array_equal(g, w) for g, w in zip(got, want)), eff
    rest = next(s for s in segs if s.fit is None)
    assert all(g is w for g, w in zip(ev.start(model, {}, rest), (rest.X0, rest.v0, rest.w0)))
