"""Close the loop: residuals of the fitted model → candidate effects → fit → held-out selection.

Error of a rollout segment s (frames k of the segment, open loop from the tracked start state):
``e_s = mean_k ( |p_sim,k − p_obs,k| + ρ · ∠(R_obs,kᵀ R_sim,k) )`` with ρ = ``rot_scale_m``
(default: the object radius), so e is in metres.

Blocks (``make_segments``): consecutive blocks of ``segment_s``; with a robot, every impulsive launch from rest
(a strike, ``launches``) gets its own block from just before the onset to where the object has settled, started
at rest (start state fitted on the frames before it). The measured sphere path is smoothed before any rollout
(``smooth_robot``): the rollouts drag the sphere kinematically, so its velocity noise would become launch speed.

Every effect acts in some contact modes (gravity in free flight, restitution at impacts, the table
offset at rest, …); its fit and its test use only the frames of those modes (for
impact effects, every frame from the first impact of a block on), in blocks with >= 3 such frames.
This keeps the contact chaos of unrelated frames out of both, and stops an effect from being
accepted for soaking up errors it does not model (e.g. a low gravity softening impacts).

Fit of an effect with parameters θ (1–3 numbers, bounded): minimise the mean training error
``E_train(θ) = mean_{s∈train} e_s(θ)`` over (at most ``max_train_segments``) training blocks where it
acts. One parameter: a coarse grid over the bounds (including
the signature's guess and the null value), then bounded Brent search in the bracket around the best
grid point. Several parameters: Nelder–Mead from the guess in coordinates scaled to the bounds,
clipped to the bounds.

Selection (greedy forward): in each round every remaining candidate is fitted on top of the effects
already accepted; on the held-out blocks where it acts, d_s = e_s(before) − e_s(after). A candidate passes when
(a) mean(d)/mean(e_before) ≥ ``min_rel_improvement``; (b) with each held-out unit's (trajectory's, or
block's for one long session) relative improvement r_u = (b̄_u − ā_u)/max(b̄_u, ā_u) of its mean errors
before and after, the one-sided (1 − α) Student-t lower bound of mean_u(r_u) is > 0 (r_u is bounded in
(−1, 1), so a few units whose rollouts diverge after a bounce cannot dominate the test, as they dominated
the mean of d_u; ``ResidualConfig.unit_statistic = "mean"`` gives the earlier rule: percentile bootstrap of
mean_u(d_u)); (c) a one-sided sign test over blocks (ties |d| ≤ ``tie_tol_rel``·median(e_before) dropped) gives
p < α — robust to the few chaotic blocks where any tiny change flips a contact outcome; and (d) the
fitted parameter is farther than its resolution from the no-effect value; and (e) the mean error over
all frames of all held-out blocks does not grow (an effect that helps its own frames but hurts the
rest is compensating for something else); (f) a directional effect (table tilt) shows its signature:
held-out blocks moving downhill and blocks moving uphill both improve (``direction_check``). The passing candidate with the largest fall of the error
over all held-out frames is accepted (a common basis: an effect judged on many frames, e.g. a near-zero
friction letting a mistimed push slide, must not outrank the one that explains them); the round repeats
until none passes or ``max_effects`` are accepted. Every judged candidate also carries its held-out error where it acts (``acting_errors``:
the error component it declares, ``Effect.component`` — position, rotation or both —, on the frames of its modes;
issue #6's measure, docs/residuals.md §1), reported and used by no rule. With ``ResidualConfig.folds`` = K >= 2 the held-out blocks are
those of K-fold cross-fitting instead of one split (``service/residuals/crossfit.py``): every unit held out once,
the fits of its fold never see it, the rules applied to the union of the folds. Both run one greedy loop,
``crossfit.crossfit``, the one split as its K = 1 case.

Nuisance refit (learned models): a model learned from the same session carries its own errors
(geometry a few millimetres to centimetres too large, inertia, CoM), which dominate the rollout error and
would otherwise be soaked up by whichever effect mimics them. Before any effect is judged, the
corrections ``ResidualConfig.nuisance`` (default for learned models: per-principal-axis geometry scale
s ∈ [0.5, 1.3]³ about the CoM with the inertia following, inertia factor, CoM shift, table height) are
fitted jointly (Nelder–Mead, all frames of the training blocks) and kept when the training error falls
by ≥ ``min_rel_improvement``; the contact modes are re-classified with the corrected geometry; effects are
judged against this corrected base. A candidate whose own fit lowers the training error (by ≥ half of
``min_rel_improvement``) or passes is refitted jointly with the corrections (so neither absorbs the
other) and judged against the same base. Corrections are reported
(``ResidualOutputs.corrections``), never accepted as effects and not put into the output model.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar
from scipy.stats import binom
from scipy.stats import t as student_t

from service.errors import InvalidInput
from service.model import ObjectModel
from service.residuals.effects import (
    NUISANCE_LEARNED,
    NUISANCE_ONLY,
    REGISTRY,
    Effect,
    apply_effects,
    is_negligible,
    null_params,
)
from service.residuals.modes import FREE, IMPACT, ROBOT, SLIDING, classify, collision_vertices, mode_statistics, object_radius, sphere_gaps
from service.residuals.types import (
    MODES,
    EffectCandidate,
    ResidualConfig,
    ResidualInputs,
    ResidualOutputs,
    RobotPath,
    SimRequest,
)
from service.transforms import make_X, mat_to_quat, quat_to_rotvec, rotation_angle, so3_exp


@dataclass(frozen=True)
class Segment:
    traj: int
    start: int
    stop: int  # exclusive
    t: np.ndarray  # (T,)
    X_obs: np.ndarray  # (T,4,4)
    tracked: np.ndarray  # (T,) bool
    mode: np.ndarray  # (T,) int
    X0: np.ndarray  # (4,4) start pose (local fit)
    v0: np.ndarray  # (3,)
    w0: np.ndarray  # (3,)
    robot: RobotPath | None
    follow_through: bool = False  # a launch block the sphere pushes on (``restitution_follow_frames``): no restitution
    launch: bool = False  # a launch block (``launches``): its release block can be cut (``release_segment``)


def local_quadratic(p: np.ndarray, half: int) -> np.ndarray:
    """(n, d) samples ``p`` (uniform steps) smoothed by a weighted local quadratic fit over ``2 half + 1`` samples,
    biweight weights (1 − (k / (half + 1))²)² at offset k (vanishing smoothly at the window's edges).

    Exact for any quadratic in time (a constant acceleration is kept), like Savitzky–Golay; unlike its equal
    weights, the smooth weights leave little noise in the sample-to-sample increments (the velocity a kinematic
    drive hands a struck object): per unit of sample noise 0.108 at half = 9 against 0.243 for the 11-sample
    Savitzky–Golay (position 0.375 against 0.455). The first and last ``half`` samples are fitted on the part of
    their window inside the data (same weights, truncated).
    """
    p = np.asarray(p, float)
    n = len(p)
    k_all = np.arange(-half, half + 1, dtype=float)
    w_all = (1.0 - (k_all / (half + 1)) ** 2) ** 2
    out = np.empty_like(p)

    def row(lo: int, hi: int) -> np.ndarray:
        """weights of samples lo..hi (offsets from the fitted sample) for the fit's value at offset 0"""
        k, w = k_all[lo + half:hi + half + 1], w_all[lo + half:hi + half + 1]
        A = np.stack([np.ones_like(k), k, k * k], 1)
        return np.linalg.solve(A.T @ (w[:, None] * A), (A * w[:, None]).T)[0]

    K = row(-half, half)
    for i in range(n):
        lo, hi = max(-half, -i), min(half, n - 1 - i)
        if lo == -half and hi == half:
            continue
        out[i] = row(lo, hi) @ p[i + lo:i + hi + 1]
    if n > 2 * half:
        from numpy.lib.stride_tricks import sliding_window_view

        win = sliding_window_view(p, 2 * half + 1, axis=0)  # (n − 2 half, d, 2 half + 1)
        out[half:n - half] = win @ K
    return out


def smooth_robot(robot: RobotPath | None, cfg: ResidualConfig) -> RobotPath | None:
    """The measured sphere path smoothed by a local quadratic fit over ``robot_smooth_s``: Savitzky–Golay
    (``robot_smooth_weights`` "box") or biweight weights (``local_quadratic``).

    The rollouts drag the sphere kinematically along this path, so its velocity at a contact sets the
    object's launch; sensor noise of σ per sample at rate f gives velocity noise ≈ √2 σ f (0.2 mm at 240 Hz:
    0.07 m/s), and the kinematic sphere hands the object the largest of those kicks (a launch 7–10 % too fast
    on the lab's strikes). Non-uniform or short logs are returned unchanged.
    """
    if robot is None or cfg.robot_smooth_s <= 0:
        return robot
    t = np.asarray(robot.t, float)
    if len(t) < 7:
        return robot
    dt = np.diff(t)
    med = float(np.median(dt))
    if med <= 0 or np.max(np.abs(dt - med)) > 0.05 * med:
        return robot
    w = int(round(cfg.robot_smooth_s / med)) | 1
    if w < 5 or w > len(t):
        return robot
    if cfg.robot_smooth_weights == "biweight":
        return dataclasses.replace(robot, p_WE=local_quadratic(robot.p_WE, w // 2))
    from scipy.signal import savgol_filter

    p = savgol_filter(np.asarray(robot.p_WE, float), w, 2, axis=0, mode="interp")
    return dataclasses.replace(robot, p_WE=p)


def _check(inputs: ResidualInputs) -> None:
    if not inputs.trajectories:
        raise InvalidInput("residuals", "no observed trajectory was given")
    for k, tr in enumerate(inputs.trajectories):
        n = len(tr.t)
        if np.shape(tr.X_WO) != (n, 4, 4):
            raise InvalidInput(f"trajectories[{k}]", f"X_WO must be (N,4,4) with N = len(t) = {n}, got {np.shape(tr.X_WO)}")
        if n > 1 and not np.all(np.diff(tr.t) > 0):
            raise InvalidInput(f"trajectories[{k}]", "times t must be strictly increasing")
        for name in ("v_WO_W", "w_WO_O"):
            a = getattr(tr, name)
            if a is not None and np.shape(a) != (n, 3):
                raise InvalidInput(f"trajectories[{k}]", f"{name} must be (N,3), got {np.shape(a)}")
        if tr.tracked is not None and np.shape(tr.tracked) != (n,):
            raise InvalidInput(f"trajectories[{k}]", "tracked must be (N,) bool")
    if inputs.robot is not None and len(inputs.robot) != len(inputs.trajectories):
        raise InvalidInput("robot", "needs one robot path (or None) per trajectory")


def start_state(t: np.ndarray, X: np.ndarray, at: int, h: float, degree: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start pose and backward-difference velocities at frame ``at`` of a short window (t, X).

    Positions and rotation vectors r = Log(R_atᵀ R) are fitted by quadratics in time (lines below 4
    frames). Semi-implicit Euler with step h started with v₀ follows p(τ) = p₀ + (v₀ + a h/2) τ + a τ²/2,
    so v₀ is the fitted curve's derivative at τ = −h/2 (likewise ω₀ for r). ``degree`` 3: cubics (with >= 6
    frames), for a one-sided window over a motion whose deceleration changes (a damped slide: its velocity from a
    quadratic is biased by the jerk, ``release_segment``); the derivative at −h/2 includes the cubic's term.
    """
    k = len(t)
    tau = t - t[at]
    cols = [np.ones(k), tau] + ([0.5 * tau**2] if k >= 4 else []) + ([tau**3 / 6.0] if degree >= 3 and k >= 6 else [])
    A = np.stack(cols, 1)
    cp, *_ = np.linalg.lstsq(A, X[:, :3, 3], rcond=None)
    R_ref = X[at, :3, :3]
    r = quat_to_rotvec(mat_to_quat(np.swapaxes(R_ref, 0, 1)[None] @ X[:, :3, :3]))
    cr, *_ = np.linalg.lstsq(A, r, rcond=None)
    acc_p = cp[2] if len(cp) > 2 else 0.0
    acc_r = cr[2] if len(cr) > 2 else 0.0
    jerk_p = 0.125 * h * h * cp[3] if len(cp) > 3 else 0.0
    jerk_r = 0.125 * h * h * cr[3] if len(cr) > 3 else 0.0
    X0 = make_X(R_ref @ so3_exp(cr[0]), cp[0])
    return X0, cp[1] - 0.5 * h * acc_p + jerk_p, cr[1] - 0.5 * h * acc_r + jerk_r


def _fit_window_ok(mode: np.ndarray) -> bool:
    """A start-state window must not straddle an impact or a flight/contact change."""
    if (mode == IMPACT).any():
        return False
    free = mode == FREE
    return bool(free.all() or (~free).all())


def flight_window(mode: np.ndarray, tracked: np.ndarray, at: int, n_max: int, lo: int = 0,
                  hi: int | None = None) -> tuple[int, int]:
    """Frames [a, b) of the free-flight stretch containing frame ``at``: tracked free-flight frames contiguous with it,
    at most ``n_max // 2`` on either side, within [lo, hi). (a, a) when ``at`` itself is not a tracked free-flight
    frame.

    The start-state fit of a block that starts in free flight (``ResidualConfig.init_fit_frames_flight``): in flight
    the centre of mass follows a parabola whatever the gravity, and a body's rotation vector relative to its pose at
    ``at`` is a line in time up to the slow change of ω by Euler's equations or a damping, so a quadratic fit over the
    whole stretch is still right and averages more pose noise than the short centred window (the spin error of the
    9-frame window, ≈ 0.1 rad/s at 148 Hz with 2.9 mrad of pose noise, is what a tumbling toss amplifies at its next
    bounce). Contact is not smooth, so the window never leaves the flight.
    """
    hi = len(mode) if hi is None else hi
    if not (lo <= at < hi and mode[at] == FREE and tracked[at]):
        return at, at
    half = max(0, n_max // 2)
    a = at
    while a > max(lo, at - half) and mode[a - 1] == FREE and tracked[a - 1]:
        a -= 1
    b = at + 1
    while b < min(hi, at + half + 1) and mode[b] == FREE and tracked[b]:
        b += 1
    return a, b


def launches(t: np.ndarray, X: np.ndarray, tracked: np.ndarray, cfg: ResidualConfig) -> list[tuple[int, int]]:
    """Impulsive starts of motion from rest (a strike) as (onset, settled) frame pairs.

    With backward-difference speeds u_k = |p_k − p_{k−1}| / dt: onset k when u_{k−1} < ``launch_rest_speed``
    and max(u_k..u_{k+2}) > ``launch_speed`` (an acceleration of ≳ 1.5 m/s², about 7× the peak of the lab's
    quasi-static strokes, which never trigger it); settled = the first frame after the peak where two
    consecutive speeds are below ``launch_rest_speed`` (capped at ``launch_max_s``).
    """
    n = len(t)
    if n < 6:
        return []
    u = np.zeros(n)
    u[1:] = np.linalg.norm(np.diff(X[:, :3, 3], axis=0), axis=1) / np.maximum(np.diff(t), 1e-9)
    out: list[tuple[int, int]] = []
    k = 1
    while k < n - 1:
        if (u[k - 1] < cfg.launch_rest_speed and u[k:k + 3].max() > cfg.launch_speed
                and tracked[max(k - 1, 0):k + 3].all()):
            peak = k + int(np.argmax(u[k:k + 3]))
            stop = peak + 1
            t_max = t[k] + cfg.launch_max_s
            while stop < n - 1 and t[stop] < t_max and not (u[stop] < cfg.launch_rest_speed and u[stop + 1] < cfg.launch_rest_speed):
                stop += 1
            out.append((k, min(stop + 1, n)))
            k = stop + 1
        else:
            k += 1
    return out


def follow_frames(mode: np.ndarray, tracked: np.ndarray, onset: int) -> int:
    """Tracked ``robot_contact`` frames of a launch block from the launch's ``onset`` (frame index in the block) on:
    the strike's contact and any re-touch of the sphere catching up with the object (the count ``--per-block`` of
    ``benchmarks/residuals.py`` prints, there over the whole block)."""
    on = (np.asarray(mode) == ROBOT) & np.asarray(tracked, bool)
    return int(on[max(onset, 0):].sum())


def make_segments(inputs: ResidualInputs, modes: list[np.ndarray], cfg: ResidualConfig) -> list[Segment]:
    """Non-overlapping rollout blocks of ``segment_s`` (auto: 0.15 s, 0.3 s with a robot) along every trajectory.

    The start state of a block comes from a quadratic fit over ``init_fit_frames`` frames centred on
    its first frame (clipped at the trajectory ends): centring keeps the velocity error of tracking
    noise ~4x below a one-sided fit. The same start state serves every model compared, so the paired
    comparison stays fair. Blocks whose fit window straddles an impact or a flight/contact change are
    skipped. With ``init_fit_frames_flight`` a block that starts in free flight has its start state fitted on its
    free-flight stretch instead (``flight_window``: up to that many frames around the start, when that is more than
    the centred window); which blocks exist does not change.

    With a robot, every impulsive launch from rest (``launches``: a strike) gets a block of its own, from
    ``launch_lead`` frames before its onset to where the object has settled (the launch, the free slide and
    the stop in one rollout, started at rest); its start state is fitted on the frames *before* the start
    (a centred window would straddle the launch, and a start inside the slide would straddle the launch or
    the stop). The regular blocks are cut around these.
    """
    segs: list[Segment] = []
    kfit = max(2, cfg.init_fit_frames)
    has_robot = inputs.robot is not None and any(r is not None for r in inputs.robot)
    seg_s = cfg.segment_s if cfg.segment_s is not None else (0.3 if has_robot else 0.15)
    for k, tr in enumerate(inputs.trajectories):
        t = np.asarray(tr.t, float)
        X = np.asarray(tr.X_WO, float)
        n = len(t)
        tracked = np.ones(n, bool) if tr.tracked is None else np.asarray(tr.tracked, bool)
        robot = inputs.robot[k] if inputs.robot is not None else None
        mode = modes[k]
        events = launches(t, X, tracked, cfg) if robot is not None else []
        ev_start = {max(a - cfg.launch_lead, 0): b for a, b in events}
        ev_onset = {max(a - cfg.launch_lead, 0): a for a, b in events}
        starts = sorted(ev_start)
        i = min(kfit // 2, max(n - kfit, 0))  # first block starts where a centred fit exists
        while i < n - 1:
            nxt = next((a for a in starts if a >= i), None)
            if i in ev_start:  # a launch block: start state from the frames up to its start (at rest)
                j = ev_start[i]
                w1 = i + 1
                w0 = max(0, w1 - kfit)
            else:
                j = int(np.searchsorted(t, t[i] + seg_s - 1e-9, side="left")) + 1
                j = min(max(j, i + 2), n)
                if n - j < cfg.min_segment_frames // 2:  # absorb a short tail
                    j = n
                if nxt is not None and j > nxt:  # stop where the next launch block starts
                    j = nxt
                w0 = max(0, min(i - kfit // 2, n - kfit))
                w1 = min(n, w0 + kfit)
                if nxt is not None and nxt < w1 and nxt > i:  # the fit window must not reach into the launch
                    w1 = nxt
                    w0 = max(0, w1 - kfit)
            at = i - w0
            ok = (
                j - i >= cfg.min_segment_frames
                and w1 - w0 >= 3
                and tracked[w0:w1].all()
                and tracked[i]
                and _fit_window_ok(mode[w0:w1])
            )
            if ok and i not in ev_start and cfg.init_fit_frames_flight > w1 - w0:
                # a start in flight: the start state from the flight's frames around it (flight_window); the
                # block was kept or skipped on the centred window above, so the blocks do not change
                a, b = flight_window(mode, tracked, i, cfg.init_fit_frames_flight, hi=nxt if nxt is not None and nxt > i else n)
                if b - a > w1 - w0:
                    w0, w1 = a, b
                    at = i - w0
            if ok:
                dt = float(np.median(np.diff(t[w0:max(w1, w0 + 2)])))
                h = dt / max(1, math.ceil(dt / cfg.sim_substep_s - 1e-9))
                X0, v0, om0 = start_state(t[w0:w1], X[w0:w1], at, h)
                follow = (cfg.restitution_follow_frames is not None and i in ev_start
                          and follow_frames(mode[i:j], tracked[i:j], ev_onset[i] - i) > cfg.restitution_follow_frames)
                segs.append(Segment(k, i, j, t[i:j], X[i:j], tracked[i:j], mode[i:j], X0, v0, om0, robot, follow,
                                    i in ev_start))
            i = j if ok else i + 1
    return segs


def release_frame(seg: Segment) -> int | None:
    """Index in a launch block of the last frame the sphere can have pushed the object on (None: no robot contact):
    the last ``robot_contact`` frame k whose backward step the sphere made at least as fast as the object along the
    object's own horizontal motion (v_sphere · d ≥ |v_object|, d the object's direction of motion over that step).

    Model-free: once the braking sphere is slower than the object it can no longer push it, even while the contact
    classifier's gap tolerance (``contact_tol_m``, 4 mm) still labels the frames ``robot_contact`` (on the lab's
    strikes 1-2 frames after the separation, at 0.2-0.35 m/s). Speeds from frame differences of X_WO (W) and of the
    sphere path interpolated at the block's times, m/s."""
    if seg.robot is None:
        return None
    on = (np.asarray(seg.mode) == ROBOT) & np.asarray(seg.tracked, bool)
    if not on.any():
        return None
    t = np.asarray(seg.t, float)
    dt = np.maximum(np.diff(t), 1e-9)[:, None]
    v_o = np.diff(seg.X_obs[:, :2, 3], axis=0) / dt
    p_s = np.stack([np.interp(t, seg.robot.t, seg.robot.p_WE[:, k]) for k in range(2)], 1)
    v_s = np.diff(p_s, axis=0) / dt
    sp = np.linalg.norm(v_o, axis=1)
    d = v_o / np.maximum(sp, 1e-9)[:, None]
    push = np.r_[False, np.sum(v_s * d, axis=1) >= sp - 1e-9] & on
    idx = np.flatnonzero(push)
    return int(idx[-1]) if len(idx) else int(np.flatnonzero(on)[0])


def release_segment(seg: Segment, gap: int, cfg: ResidualConfig, degree: int = 2) -> Segment | None:
    """The release block of a launch block: the frames from ``gap`` frames after its release (``release_frame``) to
    its end, started from the tracked state there; None when it is not a launch block, has no robot contact, or no
    usable start.

    The start state is ``start_state``'s model-free quadratic fit at the block's first frame on the frames after the
    release only: up to ``init_fit_frames`` tracked frames of the slide from the start on (modes ``sliding`` or
    ``robot_contact``; one-sided: a window across the stop would bend the quadratic), at least 4. From there the
    sphere no longer pushes, so what the struck size, the strike's timing and the sphere contact did is in the start
    state, the same for every model compared, and the block is rolled out without the sphere (``robot`` None: a hull
    left too large would otherwise meet the braking sphere a few millimetres behind it and be pushed again in the
    replay, which the observed slide did not have); what moves the rollout is what acts on the slide (friction,
    dampings, tilt). Frames X_WO in W, t in s.
    """
    if not seg.launch:
        return None
    k = release_frame(seg)
    if k is None:
        return None
    r = k + gap
    n = len(seg.t)
    if n - r < cfg.min_segment_frames:
        return None
    w1 = r
    kfit = max(2, cfg.init_fit_frames)
    while w1 < min(n, r + kfit) and seg.mode[w1] in (SLIDING, ROBOT) and seg.tracked[w1]:
        w1 += 1
    if w1 - r < 4:
        return None
    dt = float(np.median(np.diff(seg.t[r:w1])))
    h = dt / max(1, math.ceil(dt / cfg.sim_substep_s - 1e-9))
    X0, v0, w0 = start_state(seg.t[r:w1], seg.X_obs[r:w1], 0, h, degree)
    return Segment(seg.traj, seg.start + r, seg.stop, seg.t[r:], seg.X_obs[r:], seg.tracked[r:], seg.mode[r:], X0, v0,
                   w0, None, False, False)


def split_segments(segs: list[Segment], n_traj: int, cfg: ResidualConfig) -> tuple[list[Segment], list[Segment], np.ndarray]:
    """Seeded split into training and held-out segments, and the held-out resampling units.

    With >= 4 trajectories (that have blocks) whole trajectories are held out (units = trajectories); otherwise time
    blocks are (units = blocks). The held-out list is capped by random subsampling (the training
    list is subsampled per effect, among the blocks where the effect acts).
    """
    rng = np.random.default_rng(cfg.seed)
    by_traj = len({s.traj for s in segs}) >= 4
    if by_traj:
        trajs = sorted({s.traj for s in segs})
        perm = rng.permutation(trajs)
        n_held = min(max(int(round(cfg.heldout_fraction * len(trajs))), 1), len(trajs) - 1)
        held_t = set(int(x) for x in perm[:n_held])
        held = [s for s in segs if s.traj in held_t]
        train = [s for s in segs if s.traj not in held_t]
    else:
        perm = rng.permutation(len(segs))
        n_held = min(max(int(round(cfg.heldout_fraction * len(segs))), 1), len(segs) - 1)
        held = [segs[i] for i in sorted(perm[:n_held])]
        train = [segs[i] for i in sorted(perm[n_held:])]
    if len(held) > cfg.max_heldout_segments:
        held = [held[i] for i in sorted(rng.choice(len(held), cfg.max_heldout_segments, replace=False))]
    units = np.array([s.traj for s in held]) if by_traj else np.arange(len(held))
    return train, held, units


def frame_component(e: np.ndarray, component: str = "both") -> np.ndarray:
    """(T,) per-frame error of one block: ``e`` (T,) is the scalar error as it is; ``e`` (T,2) holds the parts
    [|Δp|, ρ·∠] (``Evaluator.frame_split``), of which ``component`` ("position", "rotation" or "both": their sum,
    the scalar error) is taken, m."""
    e = np.asarray(e)
    if e.ndim == 1:
        if component != "both":
            raise ValueError(f"a scalar per-frame error has no {component!r} part")
        return e
    if component == "position":
        return e[:, 0]
    if component == "rotation":
        return e[:, 1]
    if component == "both":
        return e[:, 0] + e[:, 1]
    raise ValueError(f"unknown error component {component!r}")


def reduce_blocks(frames: list[np.ndarray], masks=None, component: str = "both") -> np.ndarray:
    """Mean of each block's per-frame errors over its tracked frames (restricted to ``masks[i]``); for per-frame
    parts (T,2) of ``Evaluator.frame_split``, of their ``component`` (``frame_component``)."""
    out = np.empty(len(frames))
    for i, fr in enumerate(frames):
        e = frame_component(fr, component)
        m = np.isfinite(e) if masks is None else (np.isfinite(e) & masks[i])
        out[i] = float(e[m].mean()) if m.any() else np.nan
    return out


def acting_errors(frames: list[np.ndarray], segs: list, effect: Effect) -> np.ndarray:
    """(S,) the rollout error where ``effect`` acts, per block: the mean over the block's frames where it acts
    (``effect_mask``: its contact modes) of the error component it acts on (``Effect.component``), m; ``frames``
    are the blocks' per-frame parts (T,2) from ``Evaluator.frame_split``. Issue #6's third criterion compares the
    mean of this over the held-out blocks where the effect acts, after against before."""
    return reduce_blocks(frames, [effect_mask(sg, effect) for sg in segs], effect.component)


class Evaluator:
    """Rollout errors of a (model, effects) on a list of segments."""

    def __init__(self, simulate, table_height: float, rot_scale: float):
        self.simulate = simulate
        self.table_height = table_height
        self.rot_scale = rot_scale
        self.calls = 0

    def rollout(self, model: ObjectModel, effects: dict[str, float], seg: Segment) -> np.ndarray:
        """Poses X_WO (T,4,4) of ``model`` under ``effects`` rolled out open loop over ``seg`` from its start state
        (the same for every model compared)."""
        self.calls += 1
        req = SimRequest(model, seg.X0, seg.v0, seg.w0, seg.t, self.table_height, seg.robot, effects)
        return self.simulate(req)

    def frame_errors(self, model, effects, seg) -> tuple[np.ndarray, np.ndarray]:
        X = self.rollout(model, effects, seg)
        pos = np.linalg.norm(X[:, :3, 3] - seg.X_obs[:, :3, 3], axis=1)
        rot = rotation_angle(np.swapaxes(seg.X_obs[:, :3, :3], 1, 2) @ X[:, :3, :3])
        bad = ~np.isfinite(pos) | ~np.isfinite(rot)
        pos[bad], rot[bad] = 10.0, math.pi
        return pos, rot

    def frame_split(self, model, effects, segs) -> list[np.ndarray]:
        """Per block, the (T,2) per-frame parts of the error [|Δp|, ρ·∠], m (untracked frames NaN): the scalar
        error is their sum (``frame_component``), an effect's error where it acts one of them or both."""
        out = []
        for s in segs:
            pos, rot = self.frame_errors(model, effects, s)
            e = np.stack([pos, self.rot_scale * rot], 1)
            e[~s.tracked] = np.nan
            out.append(e)
        return out

    def frame_scalar(self, model, effects, segs) -> list[np.ndarray]:
        """Per block, the (T,) per-frame scalar error |Δp| + ρ·∠, m (untracked frames NaN)."""
        return [frame_component(e) for e in self.frame_split(model, effects, segs)]

    def errors(self, model, effects, segs, masks=None) -> np.ndarray:
        """(S,) mean scalar error per block over its tracked frames (and ``masks[i]`` if given), m."""
        return reduce_blocks(self.frame_scalar(model, effects, segs), masks)

    def by_mode(self, model, effects, segs) -> tuple[dict, dict]:
        """Mean pos/rot error per mode over all frames of ``segs``, plus overall figures."""
        return self.by_mode_groups([(model, effects, segs)])

    def by_mode_groups(self, groups) -> tuple[dict, dict]:
        """``by_mode`` over several (model, effects, segs) groups pooled frame by frame (cross-fitting: each fold's
        held-out blocks with that fold's model)."""
        P, R, M = [], [], []
        for model, effects, segs in groups:
            for s in segs:
                pos, rot = self.frame_errors(model, effects, s)
                P.append(pos[s.tracked])
                R.append(rot[s.tracked])
                M.append(s.mode[s.tracked])
        P, R, M = np.concatenate(P), np.concatenate(R), np.concatenate(M)
        table = {}
        for i, name in enumerate(MODES):
            sel = M == i
            table[name] = {
                "frames": int(sel.sum()),
                "pos_err_m": float(P[sel].mean()) if sel.any() else None,
                "rot_err_deg": float(np.degrees(R[sel].mean())) if sel.any() else None,
            }
        overall = {"pos_err_m": float(P.mean()), "rot_err_deg": float(np.degrees(R.mean()))}
        return overall, table


def effect_mask(seg: Segment, effect: Effect) -> np.ndarray:
    """(T,) frames of a block where the effect is judged: frames in its modes; for effects acting at
    impacts (restitution), every frame from the first of its frames on (the bounce or the launch follows the
    impact or strike frame); none in a launch block the sphere follows through (``Segment.follow_through``)."""
    if "impact" in effect.modes and seg.follow_through:
        return np.zeros(len(seg.t), bool)
    m = np.isin(seg.mode, [MODES.index(x) for x in effect.modes]) & seg.tracked
    if "impact" in effect.modes:
        hit = np.flatnonzero(np.isin(seg.mode, [MODES.index(x) for x in effect.modes]))
        if len(hit):
            m[hit[0]:] = True
    return m & seg.tracked


def direction_check(effect: Effect, theta, segs: list[Segment], before: np.ndarray, after: np.ndarray,
                    min_move_m: float = 0.005, min_cos: float = 0.3, min_blocks: int = 2) -> tuple[bool, str]:
    """Signature of a tilt: a uniform horizontal force makes objects moving downhill go farther and those moving
    uphill stop sooner, so a real tilt improves held-out blocks of both kinds; a tilt soaking up a model error
    (a push too short, a friction too high) helps one direction and hurts the other.

    Downhill u = horizontal part of the tilted gravity; a block's direction = its observed horizontal displacement
    over its frames (blocks moving < ``min_move_m`` or with |cos(Δp, u)| < ``min_cos`` are left out). Passes when
    each group has ≥ ``min_blocks`` blocks and a positive mean improvement.
    """
    from service.residuals.simulate import gravity_vector

    _, sim = effect.apply(None, tuple(theta)) if effect.name == "table_tilt" else (None, {})
    g = gravity_vector(sim)
    u = g[:2]
    if np.linalg.norm(u) < 1e-9:
        return False, "no downhill direction"
    u = u / np.linalg.norm(u)
    groups: dict[int, list[float]] = {1: [], -1: []}
    for sg, b, a in zip(segs, before, after):
        P = sg.X_obs[sg.tracked, :2, 3]
        if len(P) < 2:
            continue
        dp = P[-1] - P[0]
        n = float(np.linalg.norm(dp))
        if n < min_move_m:
            continue
        c = float(dp @ u) / n
        if abs(c) >= min_cos:
            groups[1 if c > 0 else -1].append(float(b - a))
    down, up = groups[1], groups[-1]
    why = (f"downhill blocks {len(down)} (mean change {np.mean(down) * 1e3 if down else float('nan'):+.2f} mm), "
           f"uphill {len(up)} ({np.mean(up) * 1e3 if up else float('nan'):+.2f} mm)")
    ok = len(down) >= min_blocks and len(up) >= min_blocks and np.mean(down) > 0 and np.mean(up) > 0
    return ok, why


def _acts_on(seg: Segment, effect: Effect, min_frames: int = 3) -> bool:
    return int(effect_mask(seg, effect).sum()) >= min_frames


def _fit(effect: Effect, guess, base_model, base_effects, chosen, ev: Evaluator, train, cfg) -> tuple[tuple, float]:
    """Minimise the training error over the effect's parameters; returns (θ, E_train(θ))."""
    lo, hi = np.array(effect.lower), np.array(effect.upper)
    cache: dict[tuple, float] = {}
    masks = [effect_mask(sg, effect) for sg in train]

    def loss(theta) -> float:
        theta = effect.clip(theta)
        key = tuple(round(x, 12) for x in theta)
        if key not in cache:
            model, sim = apply_effects(base_model, {**chosen, effect.name: theta})
            cache[key] = float(ev.errors(model, {**base_effects, **sim}, train, masks).mean())
        return cache[key]

    guess = effect.clip(guess)
    if len(lo) == 1:
        n_grid = max(5, min(9, cfg.fit_maxiter // 2))
        grid = np.unique(np.concatenate([np.linspace(lo[0], hi[0], n_grid), [guess[0]]]))
        null = null_params(effect, base_model)[0]
        if np.isfinite(null) and lo[0] <= null <= hi[0]:
            grid = np.unique(np.concatenate([grid, [null]]))
        vals = np.array([loss((g,)) for g in grid])
        b = int(np.argmin(vals))
        a_, c_ = grid[max(b - 1, 0)], grid[min(b + 1, len(grid) - 1)]
        if c_ > a_:
            res = minimize_scalar(
                lambda x: loss((x,)),
                bounds=(a_, c_),
                method="bounded",
                options={"maxiter": max(cfg.fit_maxiter - len(grid), 4), "xatol": 1e-4 * (hi[0] - lo[0])},
            )
            cand = [(grid[b],), (float(res.x),)]
        else:
            cand = [(grid[b],)]
        best = min(cand, key=loss)
        return effect.clip(best), loss(best)
    scale = hi - lo
    x0 = (np.array(guess) - lo) / scale
    simplex = [x0] + [np.clip(x0 + 0.25 * e, 0, 1) if x0[i] < 0.75 else x0 - 0.25 * e for i, e in enumerate(np.eye(len(lo)))]
    res = minimize(
        lambda z: loss(lo + np.clip(z, 0, 1) * scale),
        x0,
        method="Nelder-Mead",
        options={"maxfev": cfg.fit_maxiter, "initial_simplex": np.array(simplex), "xatol": 1e-3, "fatol": 1e-6},
    )
    best = effect.clip(lo + np.clip(res.x, 0, 1) * scale)
    return best, loss(best)


def contact_episodes(segs: list[Segment], cfg: ResidualConfig) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """The strike contacts of ``segs`` for ``contact_gap_term``: runs of consecutive tracked frames classified
    ``robot_contact`` within a block that reach a launch of the object from rest (``launches`` on the block's frames:
    a run meeting frames onset − 1 … onset + 1), where the sphere is known to have touched the object. Runs without a
    launch are left out: the classifier's gap tolerance (``contact_tol_m``, with the hull as it is) also flags a
    sphere resting or passing a few mm from the object, which says nothing about where the surface is. Returns the
    frames' observed poses X_WO (F,4,4), the sphere centres p_WE (F,3) in W, m (interpolated at the frame times
    from the block's robot path), the sphere radius, m, and the episode index of every frame (F,); None when there
    is none."""
    Xs, ps, ids, radius = [], [], [], None
    n_ep = 0
    for sg in segs:
        if sg.robot is None:
            continue
        on = (np.asarray(sg.mode) == ROBOT) & np.asarray(sg.tracked, bool)
        idx = np.flatnonzero(on)
        if not len(idx):
            continue
        onsets = [k for k, _ in launches(sg.t, sg.X_obs, np.asarray(sg.tracked, bool), cfg)]
        if not onsets:
            continue
        rb = sg.robot
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            if not any(run[0] - 1 <= k <= run[-1] + 1 for k in onsets):
                continue
            Xs.append(sg.X_obs[run])
            ps.append(np.stack([np.interp(sg.t[run], rb.t, rb.p_WE[:, i]) for i in range(3)], 1))
            ids.append(np.full(len(run), n_ep))
            n_ep += 1
            radius = float(rb.radius)
    if not Xs:
        return None
    return np.concatenate(Xs), np.concatenate(ps), radius, np.concatenate(ids)


def contact_gap_term(model: ObjectModel, episodes) -> float:
    """Mean over the strike contacts (``contact_episodes``) of |g_e|, m, where g_e is the smallest signed sphere-hull gap
    (``modes.sphere_gaps``: face-plane distance of the sphere centre minus its radius, at the observed pose) over
    the episode's frames: where the sphere pushes the object it touches the surface (g_e ≈ 0); a hull too large
    along the contact normal leaves it inside (g_e < 0), one too small short of it. The smallest gap of an episode
    is its frame nearest to the touch; the absolute mean (a median-like fit) keeps an episode without a frame at
    the touch from pulling the size far. 0 without episodes."""
    if episodes is None:
        return 0.0
    return float(np.mean(np.abs(episode_gaps(model, episodes))))


def episode_gaps(model: ObjectModel, episodes) -> np.ndarray:
    """(E,) smallest signed sphere-hull gap, m, of each strike contact of ``episodes`` (``contact_episodes``) for
    ``model`` at the observed poses (``modes.sphere_gaps``; < 0: the sphere inside the hull)."""
    X, p, radius, ids = episodes
    g = sphere_gaps(model, X, p, radius)
    g_min = np.full(int(ids[-1]) + 1, np.inf)
    np.minimum.at(g_min, ids, g)
    return g_min


def _fit_nuisance(names: list[str], model: ObjectModel, base_effects: dict, ev: Evaluator, train: list[Segment],
                  cfg: ResidualConfig, gap_segs: list[Segment] | None = None) -> tuple[dict[str, tuple], float, float]:
    """Joint fit of the nuisance corrections (all their parameters at once, Nelder–Mead from "no change" in
    coordinates scaled to the bounds) minimising the mean error over all frames of the training blocks.
    Returns ({name: θ}, E_train before, E_train after); the corrections are kept only when the training
    error falls by at least ``min_rel_improvement``, otherwise {} is returned. With ``nuisance_contact_gap_weight``
    > 0 the objective (and the test of the fall) adds that weight × ``contact_gap_term`` of the corrected model on
    the strike contacts of ``gap_segs`` (default: ``train``; the callers give all training blocks of the fold, of
    which ``train`` is a sample: strikes are a minority of the blocks); E_train stays the rollout error."""
    effs = [REGISTRY[n] for n in names]
    lo = np.concatenate([e.lower for e in effs])
    hi = np.concatenate([e.upper for e in effs])
    x0 = np.concatenate([null_params(e, model) for e in effs])
    scale = hi - lo
    sizes = np.cumsum([0] + [len(e.params) for e in effs])
    cache: dict[tuple, float] = {}

    def unpack(x) -> dict[str, tuple]:
        th = np.clip(x, lo, hi)
        return {e.name: tuple(float(v) for v in th[sizes[i]:sizes[i + 1]]) for i, e in enumerate(effs)}

    w_gap = cfg.nuisance_contact_gap_weight
    episodes = contact_episodes(train if gap_segs is None else gap_segs, cfg) if w_gap > 0 else None
    rollout: dict[tuple, float] = {}

    def loss(z) -> float:
        x = lo + np.clip(z, 0, 1) * scale
        key = tuple(np.round(x, 9))
        if key not in cache:
            m, sim = apply_effects(model, unpack(x))
            cache[key] = float(np.nanmean(ev.errors(m, {**base_effects, **sim}, train)))
            if episodes is not None:  # the objective gets the contact-gap term; the reported error stays the rollout's
                rollout[key] = cache[key]
                cache[key] += w_gap * contact_gap_term(m, episodes)
        return cache[key]

    z0 = (x0 - lo) / scale
    e0 = loss(z0)
    z = _nelder_mead(loss, z0, 0.12, cfg.nuisance_maxiter)
    if cfg.nuisance_restart == "both":  # the same budget as a candidate's joint refit: a second run from the end point
        z = min((z, _nelder_mead(loss, z, 0.12, cfg.nuisance_maxiter)), key=loss)
    e1 = loss(z)
    if episodes is not None:  # kept when the objective (rollout + gap term) falls by the margin; reported: the rollout
        keep = e1 < (1.0 - cfg.min_rel_improvement) * e0
        r0, r1 = (rollout[tuple(np.round(lo + np.clip(v, 0, 1) * scale, 9))] for v in (z0, z))
        return (unpack(lo + z * scale), r0, r1) if keep else ({}, r0, r0)
    if not (e1 < (1.0 - cfg.min_rel_improvement) * e0):
        return {}, e0, e0
    return unpack(lo + z * scale), e0, e1


def _nelder_mead(loss, z0: np.ndarray, step: float, maxfev: int) -> np.ndarray:
    """Nelder–Mead over the unit box (coordinates scaled to the bounds) from ``z0``, initial simplex of edge ``step``
    along each axis (inwards at the far side), ≤ ``maxfev`` evaluations of ``loss``; the end point clipped to the box,
    or ``z0`` when that is not lower."""
    simplex = [z0] + [np.clip(z0 + step * e, 0, 1) if z0[i] < 1.0 - step else z0 - step * e
                      for i, e in enumerate(np.eye(len(z0)))]
    res = minimize(loss, z0, method="Nelder-Mead",
                   options={"maxfev": maxfev, "initial_simplex": np.array(simplex), "xatol": 1e-3, "fatol": 1e-7})
    z = np.clip(res.x, 0, 1)
    return z if loss(z) < loss(z0) else z0


def _refine_joint(nuis: dict[str, tuple], eff: Effect, theta, chosen: dict[str, tuple], input_model: ObjectModel,
                  input_effects: dict, ev: Evaluator, train: list[Segment], cfg: ResidualConfig,
                  gap_segs: list[Segment] | None = None) -> tuple[dict[str, tuple], tuple]:
    """Refit the nuisance corrections together with a candidate effect (Nelder–Mead from the current values,
    all frames of the training blocks), so that the effect is not biased by corrections that soaked up part
    of it before it was added (and the corrections are not biased by the missing effect). With
    ``nuisance_contact_gap_weight`` the objective has ``_fit_nuisance``'s contact-gap term (on ``gap_segs``)."""
    effs = [REGISTRY[n] for n in nuis] + [eff]
    start = [nuis[n] for n in nuis] + [tuple(theta)]
    lo = np.concatenate([e.lower for e in effs])
    hi = np.concatenate([e.upper for e in effs])
    scale = hi - lo
    sizes = np.cumsum([0] + [len(e.params) for e in effs])
    x0 = np.concatenate([np.asarray(v, float) for v in start])

    def unpack(x):
        th = np.clip(x, lo, hi)
        return [tuple(float(v) for v in th[sizes[i]:sizes[i + 1]]) for i in range(len(effs))]

    cache: dict[tuple, float] = {}
    episodes = (contact_episodes(train if gap_segs is None else gap_segs, cfg)
                if cfg.nuisance_contact_gap_weight > 0 else None)

    def loss(z) -> float:
        x = lo + np.clip(z, 0, 1) * scale
        key = tuple(np.round(x, 9))
        if key not in cache:
            parts = unpack(x)
            fix = {e.name: parts[i] for i, e in enumerate(effs[:-1])}
            m, sim = apply_effects(input_model, {**fix, **chosen, eff.name: parts[-1]})
            cache[key] = float(np.nanmean(ev.errors(m, {**input_effects, **sim}, train)))
            if episodes is not None:
                cache[key] += cfg.nuisance_contact_gap_weight * contact_gap_term(m, episodes)
        return cache[key]

    z0 = (x0 - lo) / scale
    z = _nelder_mead(loss, z0, 0.06, cfg.nuisance_maxiter)  # from the inherited corrections
    if cfg.nuisance_restart != "off":  # also from "no change" (the hypothesis's own corrections); the lower kept
        x_null = np.concatenate([np.asarray(null_params(e, input_model), float) for e in effs[:-1]] + [x0[sizes[-2]:]])
        z_new = _nelder_mead(loss, (np.clip(x_null, lo, hi) - lo) / scale, 0.12, cfg.nuisance_maxiter)
        z = min((z, z_new), key=loss)
    parts = unpack(lo + z * scale)
    return {e.name: parts[i] for i, e in enumerate(effs[:-1])}, eff.clip(parts[-1])


def inadequacy(base_err: float, model: ObjectModel, pinned: list[str], corrected: bool, max_rel: float) -> str | None:
    """Why the (corrected) model is not adequate to name a missing effect, or None: its held-out error exceeds
    ``max_rel`` of the object size (half the diagonal of the geometry's principal-axes box: a CoM far off the
    shape, as in a poor learned model, must not enlarge it), or nuisance corrections ``pinned`` to their bounds."""
    Vc = collision_vertices(model)
    Vc = Vc - Vc.mean(0)
    size = 0.5 * float(np.linalg.norm(np.ptp(Vc @ np.linalg.svd(Vc, full_matrices=False)[2].T, axis=0)))
    if base_err > max_rel * size:
        return (f"the {'corrected ' if corrected else ''}model's held-out error {base_err * 1e3:.1f} mm exceeds "
                f"{max_rel:.0%} of the object size ({size * 1e3:.0f} mm, half its box diagonal)")
    if pinned:
        return f"the model's corrections {pinned} went to their bounds"
    return None


def acts_on(effect: Effect) -> dict:
    """Where an effect acts, as reported with each candidate: its contact modes and the error component."""
    return {"modes": list(effect.modes), "component": effect.component}


def not_judged(names: list[str], why_not: str) -> dict[str, EffectCandidate]:
    """Every candidate reported as not judged, with the reason the model is not adequate."""
    return {name: EffectCandidate(
        name, {}, float("nan"), float("nan"), False,
        f"not judged: {why_not}; the model does not explain the motion well enough to name a missing effect",
        round=0, acts_on=acts_on(REGISTRY[name])) for name in names}


def later_rules(ok: bool, why: str, eff, theta, model: ObjectModel, all_before: np.ndarray, all_after: np.ndarray,
                held_segs: list, rel_before: np.ndarray, rel_after: np.ndarray, on_bound: str | None) -> tuple[bool, str]:
    """Rules 6, 5, 4 and 7 (§4) after the held-out test: the mean error over all held-out frames must not grow, the
    fitted value must not sit on a bound (``on_bound``: None if it does not, else where it does, "" or e.g.
    " in fold(s) [2]"), nor within the effect's resolution of no effect, and a directional effect needs its
    heading-dependent signature on ``held_segs``. Returns (ok, reason)."""
    rest = why.removeprefix("passes; ")
    if ok and all_after.mean() > all_before.mean():
        return False, (f"rejected: makes the mean error over all held-out frames worse "
                       f"({(all_after.mean() - all_before.mean()) * 1e3:+.3f} mm); ") + rest
    if ok and on_bound is not None:
        return False, f"rejected: fitted value on its bound{on_bound} (compensating for something it does not model); " + rest
    if ok and is_negligible(eff, theta, model):
        return False, "rejected: fitted value within its resolution of no effect; " + rest
    if ok and eff.directional:
        d_ok, d_why = direction_check(eff, theta, held_segs, rel_before, rel_after)
        if not d_ok:
            return False, f"rejected: no heading-dependent signature ({d_why}); " + rest
        return ok, why + f"; {d_why}"
    return ok, why


def judged_candidate(name: str, eff, theta, guess, sig, why: str, rel_before: np.ndarray, rel_after: np.ndarray,
                     all_before: np.ndarray, all_after: np.ndarray, train_before: float, train_after: float, rnd: int,
                     blocks: dict, acting_before: np.ndarray, acting_after: np.ndarray) -> EffectCandidate:
    """A candidate that was fitted and judged (not yet accepted): its parameters and initial guess by name, its
    held-out errors before/after on its own frames (``rel_*``: the scalar error the rules judge), on all held-out
    frames (``all_*``) and where it acts (``acting_*``: the component it acts on, on its own frames; per block)."""
    return EffectCandidate(
        effect=name,
        params={k: float(v) for k, v in zip(eff.params, theta)},
        heldout_error_before=float(rel_before.mean()),
        heldout_error_after=float(rel_after.mean()),
        accepted=False,
        reason=why,
        signature=sig,
        initial_guess={k: float(v) for k, v in zip(eff.params, guess)},
        train_error_before=float(train_before),
        train_error_after=float(train_after),
        round=rnd,
        heldout_all_before=float(all_before.mean()),
        heldout_all_after=float(all_after.mean()),
        blocks=blocks,
        acts_on=acts_on(eff),
        heldout_acting_before=float(acting_before.mean()),
        heldout_acting_after=float(acting_after.mean()),
    )


def history_entry(rnd: int, cand: EffectCandidate, ok: bool, **extra) -> dict:
    """One candidate's fit of round ``rnd`` (0-based) for ``by_mode["rounds"]``."""
    return {"round": rnd + 1, "effect": cand.effect, "params": dict(cand.params), "passes": ok,
            "heldout_error_before": cand.heldout_error_before, "heldout_error_after": cand.heldout_error_after,
            "heldout_all_before": cand.heldout_all_before, "heldout_all_after": cand.heldout_all_after,
            "heldout_acting_before": cand.heldout_acting_before, "heldout_acting_after": cand.heldout_acting_after,
            "reason": cand.reason, **extra}


def accept_best(round_res: list[tuple], final: dict[str, EffectCandidate]) -> tuple | None:
    """Greedy step: of a round's results (passes, fall of the all-frame error, candidate, ...), the passing one with
    the largest fall is marked accepted in ``final`` and returned (None if none passes); the other passing ones are
    noted as explained by it."""
    passing = [r for r in round_res if r[0]]
    if not passing:
        return None
    best = max(passing, key=lambda r: r[1])
    cand = best[2]
    final[cand.effect] = dataclasses.replace(cand, accepted=True, reason="accepted: " + cand.reason.removeprefix("passes; "))
    for r in round_res:
        if r[0] and r[2].effect != cand.effect:
            final[r[2].effect] = dataclasses.replace(r[2], reason=f"passes alone but {cand.effect} explains more; refitted next round")
    return best


def unit_improvements(before: np.ndarray, after: np.ndarray, units: np.ndarray, statistic: str = "relative") -> np.ndarray:
    """Per held-out unit u, its improvement from paired block errors (S,) → (U,).

    ``"relative"``: r_u = (b̄_u − ā_u) / max(b̄_u, ā_u), with b̄_u, ā_u the unit's mean block errors before and
    after: 1 − ā/b̄ when the unit gets better, b̄/ā − 1 when it gets worse. In (−1, 1); ≈ log(b̄_u/ā_u) for small
    changes; swapping the two models flips its sign; a unit whose rollout diverges counts at most −1 (or +1).
    ``"mean"`` (earlier rule): d_u = b̄_u − ā_u in metres.
    """
    _, inv = np.unique(units, return_inverse=True)
    n = np.bincount(inv)
    b = np.bincount(inv, weights=before) / n
    a = np.bincount(inv, weights=after) / n
    if statistic == "mean":
        return b - a
    return (b - a) / np.maximum(np.maximum(b, a), 1e-12)


def unit_lower_bound(x: np.ndarray, cfg: ResidualConfig, rng) -> float:
    """One-sided (1 − α) lower confidence bound of the mean of per-unit values x (U,).

    ``"relative"``: Student-t, mean − t_{1−α, U−1} s/√U (x is bounded, so its mean is near normal already for
    U ≈ 10 held-out tosses, where a percentile bootstrap is too narrow: 7.7 % instead of 5 % false passes on
    normal noise with U = 10). ``"mean"`` (earlier rule): percentile bootstrap, resampling units.
    """
    if cfg.unit_statistic == "mean":
        idx = rng.integers(0, len(x), size=(cfg.n_bootstrap, len(x)))
        return float(np.quantile(x[idx].mean(1), cfg.alpha))
    if len(x) < 2:
        return -math.inf
    return float(x.mean() - student_t.ppf(1.0 - cfg.alpha, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x)))


def sign_test(before: np.ndarray, after: np.ndarray, cfg: ResidualConfig) -> tuple[int, int, float]:
    """Sign test over paired block errors (S,) in metres: blocks better and worse by more than ``tie_tol_rel`` of the
    median of ``before`` (ties dropped), and the one-sided p of that many better under no change."""
    d = before - after
    tol = cfg.tie_tol_rel * float(np.median(before))
    n_pos, n_neg = int(np.sum(d > tol)), int(np.sum(d < -tol))
    p_sign = float(binom.sf(n_pos - 1, n_pos + n_neg, 0.5)) if n_pos + n_neg else 1.0
    return n_pos, n_neg, p_sign


def _decide(before: np.ndarray, after: np.ndarray, units: np.ndarray, cfg: ResidualConfig, rng) -> tuple[bool, str, float]:
    """Acceptance rule on paired held-out errors (see the module docstring and docs/residuals.md §4)."""
    d_seg = before - after
    mb = float(before.mean())
    rel = float(d_seg.mean() / mb) if mb > 0 else 0.0
    x = unit_improvements(before, after, units, cfg.unit_statistic)
    lower = unit_lower_bound(x, cfg, rng)
    n_pos, n_neg, p_sign = sign_test(before, after, cfg)
    bound = (f"bootstrap {1 - cfg.alpha:.0%} lower bound {lower:+.2e} m of the mean improvement over {len(x)} units"
             if cfg.unit_statistic == "mean" else
             f"{1 - cfg.alpha:.0%} lower bound {lower:+.3f} of the mean relative improvement over {len(x)} units "
             f"(mean {x.mean():+.3f}, {int(np.sum(x > 0))} better, {int(np.sum(x < 0))} worse)")
    why = (f"held-out error {rel:+.1%} (relative fall), {bound}, better/worse on {n_pos}/{n_neg} of {len(d_seg)} blocks "
           f"(sign test p={p_sign:.3f})")
    if rel < cfg.min_rel_improvement:
        return False, f"rejected: fall below {cfg.min_rel_improvement:.0%}; " + why, rel
    if lower <= 0:
        return False, "rejected: improvement over held-out units not above noise; " + why, rel
    if p_sign >= cfg.alpha:
        return False, "rejected: improvement not consistent across blocks; " + why, rel
    return True, "passes; " + why, rel


def head_to_head(err_other: np.ndarray, err_this: np.ndarray, units: np.ndarray, cfg: ResidualConfig,
                 rng) -> tuple[bool, str]:
    """Does this candidate predict held-out blocks better than another one fitted to the same data? Paired block
    errors (S,) of the other (``err_other``) and of this one (``err_this``), in metres, on the same held-out blocks;
    rules 2 and 3 of the acceptance test with the other candidate's model in place of "before": the one-sided
    (1 − α) lower bound of the mean per-unit relative improvement is > 0, and the sign test over blocks (ties
    within ``tie_tol_rel`` of the median error dropped) gives p < α. No minimum fall (rule 1): between two effects
    that each pass on their own, any improvement beyond noise decides. Returns (better, text)."""
    x = unit_improvements(err_other, err_this, units, cfg.unit_statistic)
    lower = unit_lower_bound(x, cfg, rng)
    n_pos, n_neg, p_sign = sign_test(err_other, err_this, cfg)
    better = bool(lower > 0 and p_sign < cfg.alpha)
    txt = (f"{err_other.mean() * 1e3:.2f} -> {err_this.mean() * 1e3:.2f} mm on {len(err_this)} blocks, lower bound "
           f"{lower:+.3f} of the mean relative improvement over {len(x)} units, better/worse on {n_pos}/{n_neg} blocks "
           f"(sign test p={p_sign:.3f})")
    return better, txt


def _carried_keys() -> set[str] | None:
    """Effect keys the project's simulator registry understands (None: no registry, keep all)."""
    try:
        from service.sim import EFFECTS
    except ImportError:
        return None
    return set(EFFECTS)


def run(inputs: ResidualInputs, cfg: ResidualConfig, *, progress=None) -> ResidualOutputs:
    """Residuals by mode, candidate effects fitted on training segments, greedy held-out selection."""
    _check(inputs)
    if inputs.robot is not None:
        inputs = dataclasses.replace(inputs, robot=tuple(smooth_robot(r, cfg) for r in inputs.robot))
    report = progress or (lambda f, m: None)
    model = inputs.model
    has_robot = inputs.robot is not None and any(r is not None for r in inputs.robot)
    names = list(cfg.candidates) if cfg.candidates is not None else list(REGISTRY)
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise InvalidInput("ResidualConfig.candidates", f"unknown effects {unknown}; known: {sorted(REGISTRY)}")
    names = [n for n in names if has_robot or not REGISTRY[n].needs_robot]
    nuis_names = list(cfg.nuisance) if cfg.nuisance is not None else (
        list(NUISANCE_LEARNED) if inputs.step_residuals is not None and has_robot else [])
    bad = [n for n in nuis_names if n not in REGISTRY]
    if bad:
        raise InvalidInput("ResidualConfig.nuisance", f"unknown corrections {bad}; known: {sorted(REGISTRY)}")
    if cfg.candidates is None:
        names = [n for n in names if n not in NUISANCE_ONLY]
    names = [n for n in names if n not in nuis_names]
    report(0.0, "classifying contact modes")
    modes = [
        classify(model, tr, inputs.table_height, inputs.robot[k] if inputs.robot is not None else None, cfg)
        for k, tr in enumerate(inputs.trajectories)
    ]
    stats = mode_statistics(model, inputs.trajectories, modes, inputs.table_height, inputs.step_residuals, cfg)
    segs = make_segments(inputs, modes, cfg)
    if len(segs) < 2:
        raise InvalidInput("trajectories", f"need at least 2 rollout segments of >= {cfg.min_segment_frames} tracked frames, got {len(segs)}")

    own_sim = None
    simulate = inputs.simulate
    if simulate is None:
        from service.residuals.simulate import simulator_for

        own_sim = simulate = simulator_for(cfg)
    try:
        rot_scale = cfg.rot_scale_m if cfg.rot_scale_m is not None else object_radius(model)
        ev = Evaluator(simulate, inputs.table_height, rot_scale)
        # the greedy held-out selection: one seeded split (folds = 1) or K-fold cross-fitting, one code path
        from service.residuals.crossfit import crossfit

        return crossfit(inputs, cfg, model, names, nuis_names, stats, segs, ev, report)
    finally:
        if own_sim is not None:
            own_sim.close()
