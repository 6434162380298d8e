"""The step split at the time of impact (``service.sim.touch``): a sphere moving at a constant velocity towards a resting
box lands at Bullet's slop inside it, whatever the gap at the start of the step, and an unsplit step is untouched."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from service.sim.touch import TOUCH_OVERLAP_M, TouchSplitter, time_to_touch

H = 1.0 / 240.0
V = 0.5  # m/s along +x


def _world(gap: float):
    """A 0.3 kg box (10 cm cube) at rest in zero gravity and a free 10 kg sphere of radius 2 cm ``gap`` m behind its
    -x face moving at V; no damping, restitution 0; the sphere's contact processing threshold 0 (the splitter's
    requirement)."""
    cid = pb.connect(pb.DIRECT)
    pb.setPhysicsEngineParameter(fixedTimeStep=H, physicsClientId=cid)
    box = pb.createMultiBody(0.3, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.05] * 3, physicsClientId=cid),
                             basePosition=[0.0, 0.0, 0.0], physicsClientId=cid)
    sphere = pb.createMultiBody(10.0, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.02, physicsClientId=cid),
                                basePosition=[-0.05 - 0.02 - gap, 0.0, 0.0], physicsClientId=cid)
    pb.changeDynamics(sphere, -1, contactProcessingThreshold=0.0, linearDamping=0.0, angularDamping=0.0,
                      physicsClientId=cid)
    pb.changeDynamics(box, -1, restitution=0.0, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
    pb.resetBaseVelocity(sphere, [V, 0.0, 0.0], physicsClientId=cid)
    return cid, sphere, box


def _gap(cid: int, sphere: int, box: int) -> float:
    return min(c[8] for c in pb.getClosestPoints(sphere, box, 0.05, physicsClientId=cid))


@pytest.mark.parametrize("frac", [0.1, 0.5, 0.9])
def test_split_lands_at_the_slop(frac):
    cid, sphere, box = _world(frac * V * H)
    try:
        tau, d = time_to_touch(cid, sphere, box, H, np.array([V, 0.0, 0.0]), np.zeros(3))
        assert d == pytest.approx(frac * V * H, abs=1e-6)
        assert tau == pytest.approx((d + TOUCH_OVERLAP_M) / V, rel=1e-6)
        seen = []
        split = TouchSplitter(cid, sphere, box)
        t = split.step(H, lambda t: (np.array(pb.getBaseVelocity(sphere, physicsClientId=cid)[0]), np.zeros(3)),
                       lambda t, part: None, on_touch=lambda t: seen.append(-_gap(cid, sphere, box)))
        assert t == pytest.approx(tau)
        assert len(seen) == 1 and abs(seen[0] - TOUCH_OVERLAP_M) < 1e-7  # the contact starts at the touch
        assert pb.getPhysicsEngineParameters(physicsClientId=cid)["fixedTimeStep"] == H  # put back
        # the box takes the 10 kg sphere's momentum as a plastic impact would (restitution 0): no push-out kick
        vb = pb.getBaseVelocity(box, physicsClientId=cid)[0][0]
        assert vb == pytest.approx(V * 10.0 / 10.3, rel=0.005)
    finally:
        pb.disconnect(physicsClientId=cid)


def test_no_split_when_the_touch_is_beyond_the_step():
    cid, sphere, box = _world(1.5 * V * H)
    try:
        tau, _ = time_to_touch(cid, sphere, box, H, np.array([V, 0.0, 0.0]), np.zeros(3))
        assert tau is None
        split = TouchSplitter(cid, sphere, box)
        t = split.step(H, lambda t: (np.array([V, 0.0, 0.0]), np.zeros(3)), lambda t, part: None)
        assert t == 0.0
        assert _gap(cid, sphere, box) == pytest.approx(0.5 * V * H, abs=1e-7)
    finally:
        pb.disconnect(physicsClientId=cid)


def test_unsplit_step_kicks_the_box():
    """The same strike stepped whole: the contact starts up to v h inside and Bullet's push-out of that overlap launches
    the box faster than the impact gives (what the split removes)."""
    cid, sphere, box = _world(0.1 * V * H)
    try:
        for _ in range(3):
            pb.stepSimulation(physicsClientId=cid)
        assert pb.getBaseVelocity(box, physicsClientId=cid)[0][0] > 1.03 * V * 10.0 / 10.3
    finally:
        pb.disconnect(physicsClientId=cid)
