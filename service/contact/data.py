"""Getting trajectories into contact learning: from tracked sessions, and from trajectory files (.npz + meta.json).

Trajectory file layout (as shared/data/real): ``data.npz`` with ``states`` (N,13) float
[qw qx qy qz | x y z | wx wy wz (body) | vx vy vz (world)], ``offsets`` (n+1,) int with offsets[0] = 0 and
offsets[-1] = N, optional ``ids`` (n,) int; ``meta.json`` next to it with ``dt_s`` > 0. Quaternion signs are
made continuous per trajectory (they may flip between frames in some sources).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from service.contact.types import ContactConfig, ContactInputs, ContactOutputs
from service.errors import InvalidInput
from service.session.types import Friction
from service.transforms import mat_to_quat, quat_make_continuous

DEFAULT_MASS = 0.37


def _split_tracked(tracked: np.ndarray, min_len: int = 3) -> list[tuple[int, int]]:
    """[a, b) runs of consecutive tracked frames, at least ``min_len`` long."""
    runs, start = [], None
    for i, ok in enumerate(list(tracked) + [False]):
        if ok and start is None:
            start = i
        elif not ok and start is not None:
            if i - start >= min_len:
                runs.append((start, i))
            start = None
    return runs


def inputs_from_tracking(session, tracking_outputs, visible_points, mass) -> ContactInputs:
    """ContactInputs from a session and its tracking outputs.

    Object states from the tracked X_WO and velocities; the sphere from ``session.p_WE`` with backward-difference
    velocities (first row copies the second); the trajectory is split at lost frames (untracked stretches
    are dropped). ``mass`` None -> default 0.37 kg (``mass_declared`` False)."""
    t = tracking_outputs
    X = np.asarray(t.X_WO, float)
    quat = mat_to_quat(X[:, :3, :3])
    p = X[:, :3, 3]
    states_all = np.concatenate([quat, p, np.asarray(t.w_WO_O, float), np.asarray(t.v_WO_W, float)], -1)
    times = np.asarray(t.t, float)
    dts = np.diff(times)
    dt = float(np.median(dts)) if len(dts) else 1.0 / 30.0
    pe = np.asarray(session.p_WE, float)
    ve = np.zeros_like(pe)
    if len(pe) > 1:
        ve[1:] = np.diff(pe, axis=0) / np.maximum(dts, 1e-9)[:, None]
        ve[0] = ve[1]
    states, eps, evs = [], [], []
    for a, b in _split_tracked(np.asarray(t.tracked, bool)):
        S = states_all[a:b].copy()
        S[:, 0:4] = quat_make_continuous(S[:, 0:4])
        states.append(S)
        eps.append(pe[a:b])
        evs.append(ve[a:b])
    if not states:
        raise InvalidInput("trajectory", "no stretch of at least 3 consecutive tracked frames")
    declared = mass is not None and float(mass) > 0
    vp = None if visible_points is None or len(visible_points) == 0 else np.asarray(visible_points, float)
    init = None
    vm = getattr(t, "visible_mesh", None)
    if vm is not None and len(vm.vertices) >= 4:
        init = np.asarray(vm.vertices, float)
    return ContactInputs(
        dt=dt, states=tuple(states), ee_p_W=tuple(eps), ee_v_W=tuple(evs), ee_radius=float(session.ee_radius),
        table_height=float(session.table_height), friction=session.friction,
        mass=float(mass) if declared else DEFAULT_MASS, mass_declared=declared, visible_points_O=vp,
        init_vertices_O=init,
    )


def load_trajectories(npz_path: Path) -> tuple[list[np.ndarray], np.ndarray, float, dict]:
    """Validated (trajectories, ids, dt, meta) of a trajectory file; InvalidInput names the file and rule."""
    npz_path = Path(npz_path)
    name = str(npz_path)
    if not npz_path.is_file():
        raise InvalidInput(name, "file does not exist")
    meta_path = npz_path.with_name("meta.json")
    if not meta_path.is_file():
        raise InvalidInput(str(meta_path), "meta.json with dt_s (seconds between rows) must sit next to the .npz")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as e:
        raise InvalidInput(str(meta_path), f"not valid JSON ({e})") from None
    dt = meta.get("dt_s") if isinstance(meta, dict) else None
    if not isinstance(dt, (int, float)) or not np.isfinite(dt) or dt <= 0:
        raise InvalidInput(str(meta_path), "dt_s must be a positive number (seconds between rows)")
    try:
        z = np.load(npz_path, allow_pickle=False)
        files = set(z.files)
    except Exception as e:  # noqa: BLE001 — any unreadable archive is bad input
        raise InvalidInput(name, f"not a readable .npz archive ({e})") from None
    for key in ("states", "offsets"):
        if key not in files:
            raise InvalidInput(name, f"missing array '{key}' (need states (N,13) and offsets (n+1,))")
    S = z["states"]
    off = z["offsets"]
    if S.ndim != 2 or S.shape[1] != 13 or not np.issubdtype(S.dtype, np.floating):
        raise InvalidInput(name, f"states must be a float array (N,13) [quat wxyz, xyz, ω body, v world]; got {S.dtype} {S.shape}")
    if not np.isfinite(S).all():
        raise InvalidInput(name, "states contain NaN or infinite values")
    if off.ndim != 1 or len(off) < 2 or not np.issubdtype(off.dtype, np.integer):
        raise InvalidInput(name, "offsets must be an integer array (n+1,) with n >= 1")
    if off[0] != 0 or off[-1] != len(S) or np.any(np.diff(off) <= 0):
        raise InvalidInput(name, f"offsets must increase strictly from 0 to len(states) = {len(S)}")
    qn = np.linalg.norm(S[:, :4], axis=-1)
    if np.any(np.abs(qn - 1) > 1e-3):
        raise InvalidInput(name, "quaternions (columns 0-3) must have unit norm (within 1e-3)")
    n = len(off) - 1
    ids = z["ids"] if "ids" in files else np.arange(n)
    if ids.shape != (n,):
        raise InvalidInput(name, f"ids must have one entry per trajectory ({n})")
    if np.any(np.diff(off) < 2):
        raise InvalidInput(name, "every trajectory needs at least 2 rows")
    trajs = []
    for a, b in zip(off[:-1], off[1:]):
        X = np.asarray(S[a:b], float).copy()
        X[:, :4] = quat_make_continuous(X[:, :4])
        trajs.append(X)
    return trajs, np.asarray(ids, np.int64), float(dt), meta


def fit_trajectories(npz_path: Path, *, out_dir: Path, cfg: ContactConfig | None = None, train_ids=None,
                     mass: float | None = None, friction: Friction | None = None, table_height: float = 0.0,
                     progress=None) -> tuple[ContactOutputs, dict]:
    """Learn geometry and inertia from object trajectories without video (tosses; no end effector).

    Writes ``physible.obj``, ``inertia.json``, ``report.json`` and ``report.png`` into ``out_dir``.
    ``train_ids`` selects trajectories by id (default: all); ``cfg`` defaults to ``ContactConfig.tosses()``.
    Returns (outputs, report dict)."""
    from service.contact.fit import run

    cfg = cfg or ContactConfig.tosses()
    trajs, ids, dt, meta = load_trajectories(Path(npz_path))
    if train_ids is not None:
        want = set(int(i) for i in train_ids)
        unknown = want - set(ids.tolist())
        if unknown:
            raise InvalidInput(str(npz_path), f"train_ids not in the file: {sorted(unknown)[:10]}")
        sel = [k for k, i in enumerate(ids) if int(i) in want]
    else:
        sel = list(range(len(trajs)))
    declared = mass is not None and mass > 0
    m = float(mass) if declared else DEFAULT_MASS
    inputs = ContactInputs(
        dt=dt, states=tuple(trajs[k] for k in sel), ee_p_W=None, ee_v_W=None, ee_radius=0.0,
        table_height=float(table_height), friction=friction or Friction(), mass=m, mass_declared=declared,
        visible_points_O=None, init_vertices_O=None,
    )
    out = run(inputs, cfg, progress=progress)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out.physible_mesh.save_obj(out_dir / "physible.obj")
    V = np.asarray(out.physible_mesh.vertices)
    inertia = {
        "mass_kg": out.mass,
        "mass_declared": declared,
        "mass_note": "declared" if declared else f"not declared: default {DEFAULT_MASS} kg (mass is not observable from motion alone)",
        "com_O_m": out.com_O.tolist(),
        "inertia_O_kg_m2": out.inertia_O.tolist(),
        "principal_moments_kg_m2": np.linalg.eigvalsh(out.inertia_O).tolist(),
        "friction": {"object_table": out.friction.object_table, "object_robot": out.friction.object_robot,
                     "learned": bool(cfg.learn_friction)},
    }
    (out_dir / "inertia.json").write_text(json.dumps(inertia, indent=1))
    report = {
        "input": str(npz_path),
        "dataset": meta.get("name", ""),
        "dt_s": dt,
        "train_ids": [int(ids[k]) for k in sel],
        "transitions": int(sum(len(trajs[k]) - 1 for k in sel)),
        "mesh_half_extents_O_m": (0.5 * np.ptp(V, axis=0)).tolist(),
        "mesh_vertices": int(len(V)),
        "physible_points": int(len(out.physible_points_O)),
        "loss_history": out.loss_history.tolist(),
        "metrics": out.metrics,
        **inertia,
    }
    (out_dir / "report.json").write_text(json.dumps(report, indent=1))
    _plot(out, out_dir / "report.png")
    return out, report


def _plot(out: ContactOutputs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    ax[0].semilogy(np.maximum(out.loss_history, 1e-12))
    ax[0].set_xlabel("epoch")
    ax[0].set_ylabel("loss")
    ax[0].set_title("training loss")
    V = np.asarray(out.physible_mesh.vertices)
    for a, (i, j, lab) in zip(ax[1:], [(0, 1, "x-y"), (0, 2, "x-z")]):
        a.scatter(V[:, i], V[:, j], s=4, label="hull vertices")
        if len(out.physible_points_O):
            P = out.physible_points_O
            a.scatter(P[:, i], P[:, j], s=2, alpha=0.3, label="physible points")
        a.set_aspect("equal")
        a.set_title(f"geometry in O ({lab}), m")
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
