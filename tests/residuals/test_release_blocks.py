"""Release blocks (``ResidualConfig.release_blocks``, rule 10 of docs/residuals.md §4): for a launch block, a rollout
started after the sphere stopped pushing the object (``loop.release_frame``: the last robot-contact frame whose step
the sphere made at least as fast as the object) from the model-free start state of the frames after it
(``loop.release_segment``); a slide effect that passes rules 1-8 is refused when it does not improve the held-out
release blocks (``crossfit.release_rule``). Off by default."""

import dataclasses

import numpy as np
import pytest

from service.residuals.crossfit import release_rule
from service.residuals.effects import REGISTRY
from service.residuals.loop import Segment, release_frame, release_segment
from service.residuals.modes import REST, ROBOT, SLIDING
from service.residuals.types import ResidualConfig, RobotPath
from service.transforms import make_X

H = 1.0 / 30.0
A_SLIDE = 1.5  # m/s², the slide's deceleration


def _launch_block(n_push: int = 2, n_label: int = 4, v_rel: float = 0.45, launch: bool = True) -> Segment:
    """A launch block at 30 Hz: 2 frames at rest, the sphere pushes the box for ``n_push`` steps at 0.5 m/s, then the
    box slides free from ``v_rel`` with a constant deceleration while the sphere brakes to a stop behind it; the
    first ``n_label`` frames from the onset are labelled ``robot_contact`` (the classifier's gap tolerance holds the
    label after the separation), the slide ``sliding``, the stop ``rest``."""
    n = 20
    t = np.arange(n) * H
    x = np.zeros(n)
    xs = np.full(n, -0.08)
    k0 = 2
    for k in range(k0 + 1, k0 + 1 + n_push):  # pushed: box and sphere move together at 0.5 m/s
        x[k] = x[k - 1] + 0.5 * H
        xs[k] = xs[k - 1] + 0.5 * H
    r0 = k0 + n_push
    tau = t[r0:] - t[r0]
    t_stop = v_rel / A_SLIDE
    tt = np.minimum(tau, t_stop)
    x[r0:] = x[r0] + v_rel * tt - 0.5 * A_SLIDE * tt**2
    xs[r0:] = xs[r0] + 0.2 * np.minimum(tau, 0.1) - 1.0 * np.minimum(tau, 0.1) ** 2  # brakes: 0.2 m/s falling
    X = np.array([make_X(np.eye(3), np.array([xi, 0.0, 0.05])) for xi in x])
    mode = np.full(n, SLIDING)
    mode[:k0 + 1] = REST
    mode[tau.size and (r0 + int(np.ceil(t_stop / H)) + 1):] = REST
    mode[k0 + 1:k0 + 1 + n_label] = ROBOT
    p = np.stack([xs, np.zeros(n), np.full(n, 0.05)], 1)
    robot = RobotPath(t=t, p_WE=p, cmd_WE=p, radius=0.02)
    return Segment(0, 0, n, t, X, np.ones(n, bool), mode, X[0], np.zeros(3), np.zeros(3), robot, False, launch)


def test_release_frame_is_the_last_push_not_the_last_contact_label():
    seg = _launch_block(n_push=2, n_label=5)
    assert release_frame(seg) == 4  # frames 3, 4 pushed; 5-7 still labelled robot_contact, the sphere slower
    assert release_frame(_launch_block(n_push=3, n_label=5)) == 5
    no_contact = dataclasses.replace(seg, mode=np.where(seg.mode == ROBOT, SLIDING, seg.mode))
    assert release_frame(no_contact) is None


def test_release_segment_starts_after_the_push_with_the_slide_velocity():
    cfg = ResidualConfig()
    seg = _launch_block(n_push=2, n_label=5, v_rel=0.45)
    rel = release_segment(seg, 1, cfg)
    assert rel is not None and rel.start == 5 and rel.stop == seg.stop and len(rel.t) == len(seg.t) - 5
    assert not rel.launch and not rel.follow_through and rel.robot is None  # rolled out without the sphere
    # the box's velocity at frame 5 (one frame into the free slide), fitted on the frames after the release only;
    # the start state's velocity is the fitted curve's derivative at -h/2 (h the simulator's sub-step)
    v_true = 0.45 - A_SLIDE * H
    h = H / np.ceil(H / cfg.sim_substep_s - 1e-9)
    assert rel.v0[0] == pytest.approx(v_true + 0.5 * h * A_SLIDE, abs=2e-3)
    assert np.allclose(rel.X0[:3, 3], seg.X_obs[5, :3, 3], atol=1e-6)
    assert release_segment(seg, 2, cfg).start == 6
    assert release_segment(dataclasses.replace(seg, launch=False), 1, cfg) is None  # only launch blocks
    assert release_segment(_launch_block(v_rel=0.06), 1, cfg) is None  # a slide too short for a start state


class _Ev:
    """Stands in for ``loop.Evaluator``: the per-frame error parts of a model are the numbers it was given."""

    def __init__(self, err: dict):
        self.err = err

    def frame_split(self, model, effects, segs):
        return [np.column_stack([np.full(len(s.t), e), np.zeros(len(s.t))]) for s, e in zip(segs, self.err[model])]


def _fold(n_blocks: int):
    seg = _launch_block()
    return type("F", (), {"release": {"held": [seg] * n_blocks}, "base_effects": {}})()


@pytest.mark.parametrize("after, passes", [((1.0, 1.0, 1.0, 1.0), True), ((3.0, 3.0, 1.0, 1.0), False),
                                           ((2.5, 1.0, 3.0, 3.0), False), ((1.9, 1.9, 2.1, 2.1), False),
                                           ((1.99, 1.99, 1.99, 1.99), False)])  # within the ties: no improvement
def test_release_rule_refuses_an_effect_that_does_not_improve_the_slide_alone(after, passes):
    eff = REGISTRY["linear_damping"]
    folds = [_fold(2), _fold(2)]
    before = {"cur0": (2.0, 2.0), "cur1": (2.0, 2.0), "after0": after[:2], "after1": after[2:]}
    per = [{"after_model": ("after0", {})}, {"after_model": ("after1", {})}]
    cur = [("cur0", {}), ("cur1", {})]
    cfg = ResidualConfig(release_blocks=1, release_fit=False)  # at the launch blocks' θ_f (the _Ev stand-in)
    ok, why = release_rule(True, "passes; held-out error +20%", eff, per, folds, cur, _Ev(before), cfg)
    assert ok is passes
    assert "release blocks (position)" in why
    assert why.startswith("passes") if passes else why.startswith("rejected: does not improve the slide alone")
    ok, why2 = release_rule(False, "rejected: fall below 5%", eff, per, folds, cur, _Ev(before), cfg)
    assert ok is False and why2.startswith("rejected: fall below 5%")  # never turns a refusal into a pass


def test_release_rule_does_not_judge_on_too_few_blocks():
    eff = REGISTRY["linear_damping"]
    folds = [_fold(1), _fold(1)]
    err = {"c": (2.0,), "a": (5.0,)}
    ok, why = release_rule(True, "passes", eff, [{"after_model": ("a", {})}] * 2, folds, [("c", {})] * 2, _Ev(err),
                           ResidualConfig(release_blocks=1, release_min_blocks=3, release_fit=False))
    assert ok and "2, too few to judge" in why


def test_config_release_blocks():
    cfg = ResidualConfig()  # on by default: 1 frame after the release, at the release-fitted value, the cubic start
    assert (cfg.release_blocks, cfg.release_fit, cfg.release_blocks_degree) == (1, True, 3)
    assert ResidualConfig(release_blocks=None).release_blocks is None  # off (release_fit then does nothing)
    assert ResidualConfig(release_blocks=2).release_blocks == 2
    for v in (0, -1, 1.5, True, "1"):
        with pytest.raises(ValueError, match="release_blocks"):
            ResidualConfig(release_blocks=v)
    for v in (0, 2.0, False):
        with pytest.raises(ValueError, match="release_min_blocks"):
            ResidualConfig(release_min_blocks=v)
    assert not ResidualConfig(release_blocks=1, release_fit=False).release_fit
    for v in (1, "on", None):
        with pytest.raises(ValueError, match="release_fit must be a bool"):
            ResidualConfig(release_fit=v)


def _damped_launch_block(b: float = 2.0, v_rel: float = 0.45) -> Segment:
    """``_launch_block``'s strike, then a slide under friction and a viscous damping b (1/s): dv/dt = −μg − b v, whose
    deceleration falls as the box slows (the jerk that biases a one-sided quadratic's velocity low)."""
    seg = _launch_block(n_push=2, n_label=5, v_rel=v_rel)
    r0, mug = 4, A_SLIDE
    tau = seg.t[r0:] - seg.t[r0]
    t_stop = np.log1p(b * v_rel / mug) / b
    tt = np.minimum(tau, t_stop)
    x = seg.X_obs[r0, 0, 3] + ((v_rel + mug / b) * (1.0 - np.exp(-b * tt)) - mug * tt) / b
    X = seg.X_obs.copy()
    X[r0:, 0, 3] = x
    mode = np.where(seg.mode == REST, SLIDING, seg.mode)
    mode[:3] = REST
    mode[r0 + int(np.ceil(t_stop / H)):] = REST  # stopped
    return dataclasses.replace(seg, X_obs=X, mode=mode)


def test_release_blocks_degree_sets_rule_10s_start_state():
    from service.residuals.crossfit import release_blocks

    seg = _damped_launch_block()
    b, mug, v_rel = 2.0, A_SLIDE, 0.45
    cfg2 = ResidualConfig(release_blocks=1, release_blocks_degree=2)
    cfg3 = ResidualConfig(release_blocks=1)  # the cubic by default
    fold = lambda: type("F", (), {"release": None, "held": [seg], "train": [seg, seg]})()  # noqa: E731
    f2, f3 = fold(), fold()
    r2, r3 = release_blocks(f2, cfg2)[0], release_blocks(f3, cfg3)[0]
    assert len(release_blocks(f3, cfg3, train=True)) == 2
    assert np.allclose(r2.v0, release_segment(seg, 1, cfg2, 2).v0) and np.allclose(r3.v0, release_segment(seg, 1, cfg2, 3).v0)
    # the box's velocity at the release block's first frame (one frame into the slide), the derivative at −h/2
    s = H
    v = (v_rel + mug / b) * np.exp(-b * s) - mug / b
    h = H / np.ceil(H / cfg2.sim_substep_s - 1e-9)
    v_true = v + 0.5 * h * (mug + b * v)
    assert r2.v0[0] < v_true - 0.01  # the quadratic: low by the jerk
    assert r3.v0[0] == pytest.approx(v_true, abs=3e-3)  # the cubic: not
    for v in (1, 4, True, 2.0):
        with pytest.raises(ValueError, match="release_blocks_degree"):
            ResidualConfig(release_blocks=1, release_blocks_degree=v)
