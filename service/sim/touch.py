"""A physics step split at the time of impact of a sphere on a body (pybullet), shared by the synthetic lab's strikes
and the residual loop's replay.

Bullet steps a contact from the step in which it is found: a sphere that reaches a resting object during a step of
length h is found inside it by up to v h, and Bullet's solver pushes that overlap out through the velocity (erp d / h),
so a struck object leaves faster than the physics of the impact gives (docs/residuals-findings.md, "The launch kick"). The
event-driven treatment of an impact advances the world to the time of impact t* first, so that the contact starts at
the touch, then by the rest of the step: :class:`TouchSplitter`.

The split lands the sphere ``TOUCH_OVERLAP_M`` inside the body, Bullet's linear slop (pybullet sets
``m_linearSlop`` = 1e-5 m): the solver takes a contact's penetration as overlap − slop, so the contact starts with no
error to push out and no gap to let close (at a smaller overlap the short rest of a split step would let the bodies
approach at (slop − overlap) / part, cutting the bounce). During a part of length τ < h every error-reduction
parameter of the world is scaled by τ / h (``erp_for``), so a resting contact or a constraint corrects its error at
the same rate per second as in a whole step (Bullet's correction is erp d / τ: unscaled, a short part would push a
resting object's overlap with the table out tens of times faster).

Frames and units: W (world), m, s, m/s, m/s².
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pybullet as pb

TOUCH_OVERLAP_M = 1.0e-5  # m, the overlap the split lands the sphere at: Bullet's linear slop in pybullet's worlds
MAX_PARTS = 4  # free parts of one step at most (a landing short of the touch is followed by one more)
MIN_PART_S = 1.0e-9  # s, shorter parts are not made (the touch is now or at the end of the step)
# pybullet's error-reduction defaults (PhysicsServerCommandProcessor): non-contact (constraints) 0.2, contact 0.08,
# friction 0.2; a world that sets its own passes them to TouchSplitter
BULLET_ERPS = {"erp": 0.2, "contactERP": 0.08, "frictionERP": 0.2}


def time_to_touch(cid: int, sphere: int, body: int, span: float, v_sphere: np.ndarray, a_sphere: np.ndarray,
                  overlap: float = TOUCH_OVERLAP_M) -> tuple[float | None, float]:
    """(τ, d): the time τ in (0, span) s from now at which ``sphere`` reaches ``overlap`` m inside ``body``, or None
    (touching or inside already, not closing, or not reached within ``span``), and the closest distance d (m; inf
    beyond reach). A touch so late in the span that ``overlap`` is not reached in it (0 < d < travel ≤ d + overlap)
    gives τ = inf: the next step starts inside by less than the slop (``TouchSplitter.step``).

    The sphere moves by semi-implicit Euler, x(τ) = x + (v + a τ) τ with ``v_sphere`` (3,) m/s and ``a_sphere`` (3,)
    m/s² in W; the body at its current velocity (the closest point's, v + ω × r). The gap is Bullet's closest distance
    along its normal (``getClosestPoints``), so the landing is exact for a face and a straight path; near an edge or a
    corner, or with the body accelerating, the caller steps again (``TouchSplitter.step``)."""
    v_s, a_s = np.asarray(v_sphere, float), np.asarray(a_sphere, float)
    v_b, w_b = (np.asarray(x, float) for x in pb.getBaseVelocity(body, physicsClientId=cid))
    reach = (float(np.linalg.norm(v_s - v_b)) + float(np.linalg.norm(a_s)) * span + 1.0) * span + 2.0 * overlap
    pts = pb.getClosestPoints(sphere, body, reach, physicsClientId=cid)
    if not pts:
        return None, np.inf
    cp = min(pts, key=lambda c: c[8])
    d = float(cp[8])
    if d <= 0.0:  # touching or inside: a contact Bullet solves
        return None, d
    n = np.asarray(cp[7], float)  # contact normal on the body, pointing to the sphere
    com = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=cid)[0], float)
    v_pt = v_b + np.cross(w_b, np.asarray(cp[6], float) - com)
    c0 = -float((v_s - v_pt) @ n)  # closing speed, m/s
    alpha = -float(a_s @ n)  # closing acceleration, m/s²
    target = d + overlap
    travel = (c0 + alpha * span) * span
    if travel <= target:
        return (np.inf if travel > d else None), d
    disc = c0 * c0 + 4.0 * alpha * target
    if disc < 0.0:
        return None, d
    den = c0 + np.sqrt(disc)  # the smaller positive root of alpha τ² + c0 τ − target = 0, in its stable form
    if den <= 0.0:
        return None, d
    tau = 2.0 * target / den
    return (float(tau) if 0.0 < tau < span else None), d


def erp_for(erps: dict[str, float], part: float, h: float) -> dict[str, float]:
    """The world's error-reduction parameters (pybullet keywords) for a part of ``part`` s of a step of ``h`` s: each
    scaled by part / h, so an error d is corrected at erp d / h per second as in a whole step."""
    return {k: float(v) * part / h for k, v in erps.items()}


class TouchSplitter:
    """Steps one world, splitting a step at the time of impact of ``sphere`` on ``body`` (see the module's text).
    ``erps``: the world's error-reduction parameters (``BULLET_ERPS`` when None), scaled during a part and put back
    after it. The sphere's contact processing threshold must be 0 (``changeDynamics(contactProcessingThreshold=0)``
    before any of its manifolds exists): a point Bullet makes while the gap is still open is then not solved in the
    free parts (solved, it would bounce the bodies apart before the touch)."""

    def __init__(self, cid: int, sphere: int, body: int, erps: dict[str, float] | None = None):
        self.cid, self.sphere, self.body = cid, sphere, body
        self.erps = dict(BULLET_ERPS if erps is None else erps)
        self.slop = TOUCH_OVERLAP_M  # the world's linear slop (pybullet's), the overlap a split lands at
        self.late = False  # the last step's touch fell too late in it to reach the slop

    def step(self, h: float, motion: Callable[[float], tuple[np.ndarray, np.ndarray]],
             apply: Callable[[float, float], None], on_touch: Callable[[float], None] | None = None) -> float:
        """Advance the world by one step of ``h`` s, split at the sphere's time of impact when it falls within the
        step. Returns the time of the split (s into the step; 0.0 when not split).

        ``motion(t)``: the sphere's (velocity (3,) m/s, acceleration (3,) m/s²) over a part starting t s into the step,
        from its current state (before ``apply``). ``apply(t, part)``: sets the forces or constraint targets for a part
        of ``part`` s starting t s into the step (pybullet clears external forces after each step, so it is called once
        per part). The world's time step is put back to h. A touch too late in a step to reach the slop leaves the
        sphere inside by o < slop; the next step is taken with the world's slop set to o, so Bullet's solver sees a
        contact at zero error (with the slop it would let the bodies close at (slop − o) / h, cutting the bounce), and
        the slop is put back. ``on_touch(t)``, when given, is called at the split (after
        the free parts, before the rest of the step), e.g. to read the overlap the contact starts with."""
        cid = self.cid
        if self.late:  # the last step ended with the sphere inside by o < the slop: this step's solver sees none
            self.late = False
            pts = pb.getClosestPoints(self.sphere, self.body, self.slop, physicsClientId=cid)
            o = -min((c[8] for c in pts), default=np.inf)
            if 0.0 <= o < self.slop:
                apply(0.0, h)
                pb.setPhysicsEngineParameter(contactSlop=o, physicsClientId=cid)
                pb.stepSimulation(physicsClientId=cid)
                pb.setPhysicsEngineParameter(contactSlop=self.slop, physicsClientId=cid)
                return 0.0
        t = 0.0
        for i in range(MAX_PARTS):
            span = h - t
            v, a = motion(t)
            tau, _ = time_to_touch(cid, self.sphere, self.body, span, v, a, self.slop)
            if i == 0 and tau == np.inf:
                self.late = True
            if tau is None or not tau < span - MIN_PART_S or tau < MIN_PART_S:
                break
            apply(t, tau)
            pb.setPhysicsEngineParameter(fixedTimeStep=tau, physicsClientId=cid, **erp_for(self.erps, tau, h))
            pb.stepSimulation(physicsClientId=cid)
            t += tau
        if t == 0.0:
            apply(0.0, h)
            pb.stepSimulation(physicsClientId=cid)
            return 0.0
        if on_touch is not None:
            on_touch(t)
        rest = h - t
        apply(t, rest)
        pb.setPhysicsEngineParameter(fixedTimeStep=rest, physicsClientId=cid, **erp_for(self.erps, rest, h))
        pb.stepSimulation(physicsClientId=cid)
        pb.setPhysicsEngineParameter(fixedTimeStep=h, physicsClientId=cid, **self.erps)
        return t
