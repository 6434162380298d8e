"""Diagnosis of the toss generator's bounce (docs/residuals-findings.md, "The toss generator's bounce"). Reads the declared
restitution of the generated data: for diagnosis only, never part of the service.

    python benchmarks/toss_restitution.py drops [--speeds 1.0 1.5 2.0] [--phases 12] [--contact-breaking off 0.005 0.002 0.001]
    python benchmarks/toss_restitution.py tosses --seeds 63 64 65 66 [--contact-breaking off 0.001]

The generator (``tests.residuals.lab.simulate_tosses``) rolls the loop's simulator out at 148 Hz (sub-steps of
1/592 s = 1.69 ms). Both commands roll it out with poses at every sub-step (same sub-step, no loop).

``drops``: the cube, face down and without spin, dropped from rest so that it meets the table at v (m/s); start
heights spread over one sub-step's travel (contact phases). Per phase the rebound e' = sqrt(apex rise / drop height)
of the CoM above its resting height, and the largest upward CoM speed over the 8 sub-steps from the first pose within
1 mm of the contact over the speed two sub-steps before it (the physics of a flat landing with restitution e: both e).
Printed per declared e and threshold: mean, range and how many phases lose the bounce (speed ratio < e / 2).

``tosses``: the generator's own toss starts (20 per seed, tumbling), declared e = 0.5 and e = 0. The first landing is
located on a reference rollout with a 0.1 mm threshold (no contact point before the touch; the flight before it is the
same at every threshold): the corners within 1 mm of the table at the first such sub-step k and their mean approach
speed over the sub-step before. Per threshold, the largest mean upward speed of those corners over sub-steps
k-1 .. k+6 over that approach speed (Newton's restitution at a single contact point: e; a landing on an edge or face
also turns the cube, which lifts the corners more, so the ratio is a comparison between thresholds, not an identity).
Printed: the ratio for e = 0.5 and for e = 0, and the tosses where the e = 0.5 landing rebounds no more than the
e = 0 one (bounce lost).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _overrides import off_or_positive, positive_float, positive_int, unit_float  # noqa: E402

FPS_SUB = 592.0  # the generator's sub-step rate: 148 Hz frames, ceil((1/148) / 0.002) = 4 sub-steps each


def _cb(value):
    """``--contact-breaking`` value -> ``BulletSimulator(contact_breaking_m=...)`` (None: Bullet's default)."""
    return None if value == "off" else float(value)


def _name(cb) -> str:
    return "0.02 m (Bullet)" if cb is None else f"{cb * 1e3:g} mm"


def _corners(X: np.ndarray) -> np.ndarray:
    """(T,8,3) world positions (m) of the cube's corners for poses X (T,4,4) X_WO."""
    from tests.residuals.lab import SIDE

    c = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * SIDE / 2
    return np.einsum("tij,kj->tki", X[:, :3, :3], c) + X[:, None, :3, 3]


def _drop_rebound(sim, e: float, v: float, phase: float) -> tuple[float, float, float]:
    """(apex rebound e', rebound speed / impact speed, impact speed m/s) of a flat drop from rest meeting the table at v (m/s); ``phase`` in [0, 1) shifts the start height
    by that fraction of one sub-step's travel at impact."""
    from service.residuals.types import SimRequest
    from service.transforms import make_X
    from tests.residuals.lab import SIDE, cube_model

    h = 1.0 / FPS_SUB
    drop = v**2 / (2 * 9.81) + phase * v * h
    z0 = SIDE / 2 + drop
    t = np.arange(int((np.sqrt(2 * drop / 9.81) * 2.2 + 0.05) * FPS_SUB)) * h
    X = sim(SimRequest(cube_model(), make_X(np.eye(3), np.array([0, 0, z0])), np.zeros(3), np.zeros(3), t, 0.0, None,
                       {"restitution": e}))
    z = X[:, 2, 3]
    k = int(np.argmin(z[: int(np.sqrt(2 * drop / 9.81) / h) + 10]))  # the landing
    rise = max(float(z[k:].max()) - SIDE / 2, 0.0)
    vz = np.diff(z) / h
    j = int(np.flatnonzero(z - SIDE / 2 < 1e-3)[0])  # first pose within 1 mm of the contact height
    return float(np.sqrt(rise / drop)), float(vz[j : j + 8].max() / -vz[j - 2]), float(-vz[j - 2])


def drops(args) -> None:
    from service.residuals.simulate import BulletSimulator

    phases = (np.arange(args.phases) + 0.5) / args.phases
    for v in args.speeds:
        for e in args.e:
            for cb in args.contact_breaking:
                with BulletSimulator(0.002, contact_breaking_m=_cb(cb)) as sim:
                    A = np.array([_drop_rebound(sim, e, v, ph) for ph in phases])
                r, q = A[:, 0], A[:, 1]
                print(f"flat drop at {v:.2f} m/s, declared e {e:.2f}, contact breaking {_name(_cb(cb))}: apex e' mean "
                      f"{r.mean():.3f} (range {r.min():.3f}-{r.max():.3f}); rebound speed / impact speed mean "
                      f"{q.mean():.3f} (range {q.min():.3f}-{q.max():.3f}); bounce lost (speed ratio < e/2) in "
                      f"{int((q < e / 2).sum())}/{len(q)}; apex " + " ".join(f"{x:.2f}" for x in r)
                      + "; speed " + " ".join(f"{x:.2f}" for x in q), flush=True)


def _landing(X: np.ndarray) -> tuple[int, np.ndarray, float]:
    """First landing of poses X (T,4,4) at every sub-step: (step k of the first corner within 1 mm of the table,
    indices of the corners within 1 mm then, their mean normal speed (m/s, > 0 approaching) over the sub-step
    before k)."""
    C = _corners(X)
    k = int(np.flatnonzero(C[..., 2].min(1) < 1e-3)[0])
    idx = np.flatnonzero(C[k, :, 2] < 1e-3)
    return k, idx, float(-(C[k - 1, idx, 2] - C[k - 2, idx, 2]).mean() * FPS_SUB)


def _rebound(X: np.ndarray, k: int, idx: np.ndarray) -> float:
    """Largest mean z speed (m/s) of the corners ``idx`` over the sub-steps k-1 .. k+6 of poses X."""
    vz = np.diff(_corners(X)[:, idx, 2], axis=0).mean(1) * FPS_SUB
    return float(vz[k - 1 : k + 7].max())


def tosses(args) -> None:
    from service.residuals.simulate import BulletSimulator
    from service.residuals.types import SimRequest
    from tests.residuals.lab import cube_model, toss_starts

    t = np.arange(int(0.45 * FPS_SUB)) / FPS_SUB
    starts = [s for seed in args.seeds for s in toss_starts(20, seed)]
    with BulletSimulator(0.002, contact_breaking_m=1e-4) as ref:  # the touch: no contact point before it
        land = [_landing(ref(SimRequest(cube_model(), X0, v0, w0, t, 0.0, None, {}))) for X0, v0, w0 in starts]
    vin = np.array([v for _, _, v in land])
    for cb in args.contact_breaking:
        R = np.zeros((len(starts), 2))
        with BulletSimulator(0.002, contact_breaking_m=_cb(cb)) as sim:
            for i, ((X0, v0, w0), (k, idx, v)) in enumerate(zip(starts, land)):
                for j, e in enumerate((args.e_toss, 0.0)):
                    R[i, j] = _rebound(sim(SimRequest(cube_model(), X0, v0, w0, t, 0.0, None, {"restitution": e})), k, idx) / v
        lost = R[:, 0] <= R[:, 1] + 0.05
        print(f"tosses of seeds {args.seeds}, contact breaking {_name(_cb(cb))}: {len(R)} first landings (approach "
              f"speed of the landing corners {vin.min():.2f}-{vin.max():.2f} m/s); rebound / approach with e {args.e_toss}: "
              f"median {np.median(R[:, 0]):.3f}, mean {R[:, 0].mean():.3f}, quartiles {np.percentile(R[:, 0], 25):.3f}-"
              f"{np.percentile(R[:, 0], 75):.3f}; with e 0: median {np.median(R[:, 1]):.3f}; bounce lost (e {args.e_toss} "
              f"ratio <= e 0 ratio + 0.05) in {int(lost.sum())}/{len(R)}; e {args.e_toss} minus e 0: median "
              f"{np.median(R[:, 0] - R[:, 1]):.3f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("drops")
    d.add_argument("--speeds", type=positive_float, nargs="+", default=[1.0, 1.5, 2.0])
    d.add_argument("--e", type=unit_float, nargs="+", default=[0.3, 0.5, 0.7])
    d.add_argument("--phases", type=positive_int, default=12)
    d.add_argument("--contact-breaking", type=off_or_positive, nargs="+", default=["off", "0.005", "0.002", "0.001"])
    s = sub.add_parser("tosses")
    s.add_argument("--seeds", type=int, nargs="+", default=[63, 64, 65, 66])
    s.add_argument("--e-toss", type=unit_float, default=0.5)
    s.add_argument("--contact-breaking", type=off_or_positive, nargs="+", default=["off", "0.002", "0.001"])
    args = ap.parse_args()
    print("command:", " ".join(["python", *sys.argv]))
    {"drops": drops, "tosses": tosses}[args.cmd](args)


if __name__ == "__main__":
    main()
