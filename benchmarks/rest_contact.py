"""Diagnosis of resting contact in the loop's simulator (docs/residuals-findings.md, "Resting contact at the contact breaking
threshold"): the cube placed at rest on the table, rolled out for 2 s per contact breaking threshold and collision margin.

    python benchmarks/rest_contact.py [--thresholds 0.0005 0.001 0.002 0.005 off] [--margins 0 0.001 0.004]
    python benchmarks/rest_contact.py --real [--thresholds 0.001 off] [--offsets 0 -0.00113] [--friction 0.205]
    (either with [--persist M]: the simulator's contact_persist_m)

Per case: the drift of the pose over 2 s (CoM horizontal travel, height change, rotation) against its start, the CoM
height above the table minus the half side (the resting gap; < 0 is penetration), the number of contact points per
sub-step (min / median / max) and how many sub-steps change the count (drop and re-form). Starts: flat face down at the touch
("touch"), 0.5 mm in ("in"), 0.5 mm above ("above"); tilted 5 mrad about x with one edge on the table ("tilt");
released 1 cm above the table on an edge, tilted 0.3 rad ("rock": lands and rocks onto its face); flat at the touch
sliding at 0.5 m/s ("slide": stops after 8.5 cm at mu 0.15); flat 1.8 mm in the table (the real tosses' apparent
depth at rest) sliding at 0.3 m/s and sinking at 2 cm/s ("deep"; its "gap" is then read over the first 0.15 s, mean).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _overrides import finite_float, nonnegative_float, off_or_positive, positive_float  # noqa: E402

STARTS = ("touch", "in", "above", "tilt", "rock", "slide", "deep")  # how a rest begins (module docstring)


def rest(cb, margin: float, start: str, seconds: float = 2.0, fps: float = 148.0, substep: float = 0.002,
         friction: float = 0.15, persist: float | None = None):
    """Rest rollout of the cube; returns a dict of drift and contact figures (m, rad, counts)."""
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import SimRequest
    from service.transforms import make_X, so3_exp
    from tests.residuals.lab import SIDE, TableContacts, cube_model

    R = np.eye(3)
    z0 = SIDE / 2
    if start == "in":
        z0 -= 0.0005
    elif start == "above":
        z0 += 0.0005
    elif start == "tilt":
        R = so3_exp(np.array([0.005, 0.0, 0.0]))
        z0 += 0.5 * SIDE * 0.005
    elif start == "rock":  # released 1 cm above the touch on an edge, tilted 0.3 rad: lands, rocks onto its face
        R = so3_exp(np.array([0.3, 0.0, 0.0]))
        z0 = float((np.abs(R) @ np.full(3, SIDE / 2))[2]) + 0.01
    elif start == "deep":  # as the real tosses' data: flat, 1.8 mm in the table, sliding at 0.3 m/s, sinking 2 cm/s
        z0 -= 0.0018
    v0 = {"slide": np.array([0.5, 0.0, 0.0]), "deep": np.array([0.3, 0.0, -0.02])}.get(start, np.zeros(3))
    t = np.arange(int(seconds * fps) + 1) / fps
    with BulletSimulator(substep, collision_margin=margin, contact_breaking_m=cb, contact_persist_m=persist) as sim:
        proxy = TableContacts.attach(sim)
        X = sim(SimRequest(cube_model(friction=(friction, friction)), make_X(R, np.array([0.0, 0.0, z0])), v0,
                           np.zeros(3), t, 0.0, None, {}))
    n = np.asarray(proxy.counts)
    half = len(t) // 2  # the second second: after any settling (a slide stops at 0.34 s, a rock within 0.5 s)
    Xs = X[half:]
    xy = Xs[:, :2, 3] - Xs[0, :2, 3]
    ang = np.array([np.arccos(np.clip((np.trace(Xs[0, :3, :3].T @ Xi[:3, :3]) - 1) / 2, -1, 1)) for Xi in Xs])
    return {
        "xy_1s": float(np.linalg.norm(xy, axis=1).max()),
        "xy_2s": float(np.linalg.norm(X[-1, :2, 3] - X[0, :2, 3])),
        "rot_1s": float(ang.max()),
        "gap": float(X[1:23, 2, 3].mean() - SIDE / 2) if start == "deep" else float(X[-1, 2, 3] - SIDE / 2),
        "z_range_1s": float(np.ptp(Xs[:, 2, 3])),
        "n": (int(n.min()), float(np.median(n)), int(n.max())),
        "changes": int((np.diff(n) != 0).sum()),
        "steps": len(n),
        "xy_end": X[-1, :2, 3].copy(),
        "depth": float(np.nanmedian(proxy.depth)) if np.isfinite(proxy.depth).any() else float("nan"),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--thresholds", type=off_or_positive, nargs="+", default=["0.0005", "0.001", "0.002", "0.005", "off"])
    ap.add_argument("--margins", nargs="+", type=nonnegative_float, default=[0.0, 0.001, 0.004])
    ap.add_argument("--starts", nargs="+", default=list(STARTS), choices=STARTS)
    ap.add_argument("--real", action="store_true", help="the real tosses' blocks from rest or sliding instead")
    ap.add_argument("--offsets", nargs="+", type=finite_float, default=[0.0, -0.00113])
    ap.add_argument("--friction", type=nonnegative_float, default=0.205)
    ap.add_argument("--persist", type=positive_float, default=None, help="contact_persist_m of the simulator (default off)")
    args = ap.parse_args(argv)
    if args.real:
        return real_rests(args.thresholds, args.offsets, {"friction_object_table": args.friction}, persist=args.persist)
    for margin in args.margins:
        for th in args.thresholds:
            cb = None if th == "off" else float(th)
            for start in args.starts:
                r = rest(cb, margin, start, persist=args.persist)
                print(f"margin {margin * 1e3:g} mm, threshold {'0.02 m' if cb is None else f'{cb * 1e3:g} mm'}, start "
                      f"{start:5s}: drift in the 2nd s xy {r['xy_1s'] * 1e3:.3f} mm, rot {np.degrees(r['rot_1s']):.4f} deg,"
                      f" z range {r['z_range_1s'] * 1e3:.3f} mm; xy over 2 s {r['xy_2s'] * 1e3:.3f} mm; gap "
                      f"{r['gap'] * 1e3:+.3f} mm; contact points min/med/max {r['n']}, count changes "
                      f"{r['changes']}/{r['steps']}; median distance {r['depth'] * 1e3:+.3f} mm; end xy "
                      f"({r['xy_end'][0] * 1e3:.3f}, {r['xy_end'][1] * 1e3:.3f}) mm", flush=True)



def real_rests(thresholds, offsets, effects: dict, block: int = 22, max_blocks: int = 400, persist=None) -> None:
    """The real ContactNets tosses: blocks of ``block`` frames (0.15 s at 148 Hz) that start on a frame the loop
    classifies as rest or sliding, replayed from the data's start state with ``effects`` per threshold and table
    offset; mean position error (mm) by the data's mode over the block's frames."""
    from benchmarks.residuals import REAL, cube_model as real_cube, load_tosses
    from service.residuals.modes import classify
    from service.residuals.types import MODES
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import ResidualConfig, SimRequest
    from tests.residuals.lab import TableContacts

    cfg = ResidualConfig()
    model = real_cube()
    starts = []
    for traj in load_tosses(REAL, None, 0):
        mode = classify(model, traj, 0.0, None, cfg)
        for k in range(0, len(traj.t) - block, block // 2):
            if MODES[mode[k]] in ("rest", "sliding"):
                starts.append((traj, mode, k))
    starts = starts[:: max(1, len(starts) // max_blocks)][:max_blocks]
    print(f"{len(starts)} blocks of {block} frames starting at rest or sliding", flush=True)
    for th in thresholds:
        cb = None if th == "off" else float(th)
        for off in offsets:
            err = {m: [] for m in MODES}
            with BulletSimulator(0.002, contact_breaking_m=cb, contact_persist_m=persist) as sim:
                proxy = TableContacts.attach(sim)
                for traj, mode, k in starts:
                    sl = slice(k, k + block)
                    X = sim(SimRequest(model, traj.X_WO[k], traj.v_WO_W[k], traj.w_WO_O[k], traj.t[sl], 0.0, None,
                                       {**effects, "table_offset": off}))
                    e = np.linalg.norm(X[:, :3, 3] - traj.X_WO[sl, :3, 3], axis=1)
                    for j in range(1, block):
                        err[MODES[mode[k + j]]].append(e[j])
            allf = np.concatenate([np.asarray(v) for v in err.values() if v])
            print(f"threshold {'0.02 m' if cb is None else f'{cb * 1e3:g} mm'}, table offset {off * 1e3:+.2f} mm: "
                  f"all {allf.mean() * 1e3:.3f} mm; contact points per sub-step {np.mean(proxy.counts):.2f}, "
                  f"count changes {np.mean(np.diff(proxy.counts) != 0):.1%} of sub-steps; " + ", ".join(f"{m} {np.mean(v) * 1e3:.3f} ({len(v)})"
                                                                for m, v in err.items() if v), flush=True)


if __name__ == "__main__":
    main()
