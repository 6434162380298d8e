"""Forward kinematics of the Franka Panda: joint angles -> end-effector sphere centre in W.

p_WE = p_WF + R_WF @ tip_offset, where X_WF is the pose of the flange ``panda_link8`` computed from the
URDF ``franka_panda/panda.urdf`` shipped in ``pybullet_data`` (base fixed at the world origin: W is the
robot base frame), and ``tip_offset`` is the sphere centre in the flange frame (m). The default
[0, 0, 0.1265] puts the centre 0.107 + 0.1265 = 0.2335 m from the ``panda_link7`` origin along its z axis.
The URDF agrees with the Panda's published (modified, Craig) DH parameters; the tests compare both.
A private DIRECT pybullet client is opened per call and closed afterwards (no global state).
"""

from __future__ import annotations

import numpy as np

FLANGE_LINK = "panda_link8"
ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))


def panda_flange_poses(q: np.ndarray) -> np.ndarray:
    """Flange poses X_WF (M,4,4) for joint angles q (M,7) in radians."""
    import pybullet as pb
    import pybullet_data

    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 7:
        raise ValueError(f"q must be (M,7), got {q.shape}")
    cid = pb.connect(pb.DIRECT)
    try:
        urdf = f"{pybullet_data.getDataPath()}/franka_panda/panda.urdf"
        robot = pb.loadURDF(urdf, useFixedBase=True, physicsClientId=cid)
        name_to_joint: dict[str, int] = {}
        link_index = -2
        for j in range(pb.getNumJoints(robot, physicsClientId=cid)):
            info = pb.getJointInfo(robot, j, physicsClientId=cid)
            name_to_joint[info[1].decode()] = j
            if info[12].decode() == FLANGE_LINK:
                link_index = j
        if link_index < 0:
            raise RuntimeError(f"{FLANGE_LINK} not found in {urdf}")
        joints = [name_to_joint[n] for n in ARM_JOINTS]
        out = np.empty((len(q), 4, 4))
        for k, qk in enumerate(q):
            for j, v in zip(joints, qk):
                pb.resetJointState(robot, j, float(v), physicsClientId=cid)
            st = pb.getLinkState(robot, link_index, computeForwardKinematics=True, physicsClientId=cid)
            pos, quat_xyzw = st[4], st[5]
            R = np.asarray(pb.getMatrixFromQuaternion(quat_xyzw, physicsClientId=cid)).reshape(3, 3)
            out[k] = np.eye(4)
            out[k, :3, :3] = R
            out[k, :3, 3] = pos
        return out
    finally:
        pb.disconnect(physicsClientId=cid)


def panda_joint_limits() -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) limits (7,) in radians of the arm joints, from the same URDF."""
    import pybullet as pb
    import pybullet_data

    cid = pb.connect(pb.DIRECT)
    try:
        robot = pb.loadURDF(f"{pybullet_data.getDataPath()}/franka_panda/panda.urdf", useFixedBase=True, physicsClientId=cid)
        lim = {}
        for j in range(pb.getNumJoints(robot, physicsClientId=cid)):
            info = pb.getJointInfo(robot, j, physicsClientId=cid)
            lim[info[1].decode()] = (info[8], info[9])
        lo = np.array([lim[n][0] for n in ARM_JOINTS])
        hi = np.array([lim[n][1] for n in ARM_JOINTS])
        return lo, hi
    finally:
        pb.disconnect(physicsClientId=cid)


def panda_sphere_centres(q: np.ndarray, tip_offset: np.ndarray) -> np.ndarray:
    """Sphere centres p_WE (M,3) for joint angles q (M,7) and the offset (3,) in the flange frame."""
    X = panda_flange_poses(q)
    return X[:, :3, 3] + X[:, :3, :3] @ np.asarray(tip_offset, dtype=float)
