"""Sim-to-recover data for the residual-loop tests: a known model, a hidden effect, simulated tosses.

The hidden effect is written to a sidecar dict that only the test reads; the loop gets the base model
(without the effect) and the simulated trajectories.
"""

from __future__ import annotations

import numpy as np
import trimesh

from service.mesh import Mesh
from service.model import ObjectModel
from service.residuals.simulate import BulletSimulator
from service.residuals.types import ObservedTrajectory, SimRequest
from service.session.types import Friction
from service.transforms import make_X, so3_exp

SIDE = 0.1048
MASS = 0.37
# The generator's contact breaking threshold (m; ``BulletSimulator(contact_breaking_m=...)``). With Bullet's 0.02 m the
# contact point of a landing exists many sub-steps before the touch and the generated bounce is not the declared e:
# 46 of 80 first landings of tosses declared e = 0.5 rebound like e = 0, and flat drops at 1-2 m/s rebound at
# 0.32-0.43 x (mean) instead of 0.5; with 1 mm no landing loses its bounce and flat drops rebound at 0.48 x
# (docs/residuals-findings.md, "The toss generator's bounce"; benchmarks/toss_restitution.py).
TOSS_CONTACT_BREAKING_M: float | None = 0.001


class TableContacts:
    """Proxy of the pybullet module a ``BulletSimulator`` steps with: after every sub-step it records the object's
    (body 1) contact points with the table (body 0), their number (``counts``) and the deepest one's signed distance
    (``depth``, m, negative inside; NaN without contact). ``TableContacts.attach(sim)`` installs it on ``sim``."""

    def __init__(self, p):
        self._p = p
        self.counts: list[int] = []
        self.depth: list[float] = []

    @classmethod
    def attach(cls, sim: BulletSimulator) -> "TableContacts":
        proxy = cls(sim._p)
        sim._p = proxy
        return proxy

    def __getattr__(self, name):
        return getattr(self._p, name)

    def stepSimulation(self, physicsClientId=0):
        self._p.stepSimulation(physicsClientId=physicsClientId)
        cps = self._p.getContactPoints(bodyA=1, bodyB=0, physicsClientId=physicsClientId)
        self.counts.append(len(cps))
        self.depth.append(min((c[8] for c in cps), default=np.nan))


def cube_model(effects=None, friction=(0.15, 0.15)) -> ObjectModel:
    m = Mesh.from_trimesh(trimesh.creation.box((SIDE,) * 3))
    inertia = np.eye(3) * MASS * SIDE**2 / 6
    return ObjectModel(m, (m,), MASS, True, np.zeros(3), inertia, Friction(*friction), dict(effects or {}))


def toss_starts(n: int, seed: int):
    """n random toss start states (X_WO0, v0, w0): centre 11–19 cm above the table, thrown forward and down."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        R = so3_exp(rng.normal(size=3) * 1.0)
        X = make_X(R, np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 0.11 + rng.uniform(0.0, 0.08)]))
        v = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.2, 0.2), rng.uniform(-0.6, 0.0)])
        w = rng.normal(size=3) * 3.0
        out.append((X, v, w))
    return out


def simulate_tosses(model: ObjectModel, hidden: dict[str, float], n: int = 8, seed: int = 0, fps: float = 148.0,
                    duration: float = 0.7, noise_m: float = 0.0,
                    contact_breaking_m: float | None = TOSS_CONTACT_BREAKING_M) -> tuple[ObservedTrajectory, ...]:
    """Tosses of ``model`` with the hidden effect ``hidden``, sampled at ``fps`` (poses only), simulated with the
    contact breaking threshold ``contact_breaking_m`` (m; None = Bullet's 0.02 m, which loses bounces)."""
    rng = np.random.default_rng(seed + 1000)
    t = np.arange(int(duration * fps)) / fps
    sim = BulletSimulator(0.002, contact_breaking_m=contact_breaking_m)
    trajs = []
    try:
        for X0, v0, w0 in toss_starts(n, seed):
            X = sim(SimRequest(model, X0, v0, w0, t, 0.0, None, dict(hidden)))
            if noise_m > 0:
                X = X.copy()
                X[:, :3, 3] += rng.normal(scale=noise_m, size=(len(t), 3))
                X[:, :3, :3] = so3_exp(rng.normal(scale=noise_m / (SIDE / 2), size=(len(t), 3))) @ X[:, :3, :3]
            trajs.append(ObservedTrajectory(t=t, X_WO=X))
    finally:
        sim.close()
    return tuple(trajs)


def push_session(model: ObjectModel, hidden: dict[str, float], seed: int = 0, fps: float = 30.0, strokes: int = 6,
                 noise_m: float = 0.0):
    """One pushing session: the sphere pushes the resting cube in ``strokes`` straight strokes of random
    heading (approach, push 6 cm at 0.12 m/s, retreat). Returns (trajectory, robot path)."""
    from service.residuals.types import RobotPath

    rng = np.random.default_rng(seed)
    r = 0.0195
    t_knots, p_knots = [0.0], [np.array([-0.25, 0.0, 0.3])]
    X = make_X(np.eye(3), np.array([0.0, 0.0, SIDE / 2]))
    sim = BulletSimulator(0.002)
    centre = np.zeros(2)
    T_total = strokes * 2.0
    t = np.arange(int(T_total * fps)) / fps
    # plan strokes around a nominal cube centre that drifts with the pushes (open-loop plan)
    for k in range(strokes):
        ang = rng.uniform(-np.pi, np.pi)
        d = np.array([np.cos(ang), np.sin(ang)])
        start = centre - d * (SIDE / 2 + r + 0.03)
        h = rng.uniform(0.02, 0.04)
        t0 = 2.0 * k
        t_knots += [t0 + 0.3, t0 + 0.5, t0 + 1.5, t0 + 1.8]
        p_knots += [np.r_[start, 0.3], np.r_[start, h], np.r_[start + d * 0.12, h], np.r_[start + d * 0.12, 0.3]]
        centre = centre + d * 0.06
    path = RobotPath(np.array(t_knots), np.array(p_knots), None, r)
    try:
        Xs = sim(SimRequest(model, X, np.zeros(3), np.zeros(3), t, 0.0, path, dict(hidden)))
    finally:
        sim.close()
    if noise_m > 0:
        nr = np.random.default_rng(seed + 1000)
        Xs = Xs.copy()
        Xs[:, :3, 3] += nr.normal(scale=noise_m, size=(len(t), 3))
    return ObservedTrajectory(t=t, X_WO=Xs), path
