"""Forward kinematics of the Franka Panda: joint angles -> end-effector sphere centre in W.

p_WE = p_WF + R_WF @ tip_offset, where X_WF is the pose of the flange ``panda_link8`` computed from the
URDF ``franka_panda/panda.urdf`` shipped in ``pybullet_data`` (base fixed at the world origin: W is the
robot base frame), and ``tip_offset`` is the sphere centre in the flange frame (m). The default
[0, 0, 0.1265] puts the centre 0.107 + 0.1265 = 0.2335 m from the ``panda_link7`` origin along its z axis.
The URDF agrees with the Panda's published (modified, Craig) DH parameters; the tests compare both.
A private DIRECT pybullet client is opened per ``PandaModel`` and closed with it (no global state).
"""

from __future__ import annotations

import numpy as np

FLANGE_LINK = "panda_link8"
ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))


class PandaModel:
    """The Panda URDF loaded in a private pybullet DIRECT client; use as a context manager."""

    def __init__(self) -> None:
        import pybullet as pb
        import pybullet_data

        self._pb = pb
        self._cid = pb.connect(pb.DIRECT)
        try:
            urdf = f"{pybullet_data.getDataPath()}/franka_panda/panda.urdf"
            # kinematics only: skip the meshes (loading them costs ~1 s, the frames do not depend on them)
            flags = pb.URDF_IGNORE_VISUAL_SHAPES | pb.URDF_IGNORE_COLLISION_SHAPES
            self._robot = pb.loadURDF(urdf, useFixedBase=True, flags=flags, physicsClientId=self._cid)
            joints: dict[str, tuple[int, float, float]] = {}
            self._flange = -1
            for j in range(pb.getNumJoints(self._robot, physicsClientId=self._cid)):
                info = pb.getJointInfo(self._robot, j, physicsClientId=self._cid)
                joints[info[1].decode()] = (j, info[8], info[9])
                if info[12].decode() == FLANGE_LINK:
                    self._flange = j
            if self._flange < 0:
                raise RuntimeError(f"{FLANGE_LINK} not found in {urdf}")
            self._joints = [joints[n][0] for n in ARM_JOINTS]
            self.lower = np.array([joints[n][1] for n in ARM_JOINTS])  # (7,) rad
            self.upper = np.array([joints[n][2] for n in ARM_JOINTS])  # (7,) rad
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self._cid is not None:
            self._pb.disconnect(physicsClientId=self._cid)
            self._cid = None

    def __enter__(self) -> PandaModel:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def flange_poses(self, q: np.ndarray) -> np.ndarray:
        """Flange poses X_WF (M,4,4) for joint angles q (M,7) in radians."""
        pb, cid = self._pb, self._cid
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != 7:
            raise ValueError(f"q must be (M,7), got {q.shape}")
        out = np.zeros((len(q), 4, 4))
        out[:, 3, 3] = 1.0
        for k, qk in enumerate(q):
            for j, v in zip(self._joints, qk):
                pb.resetJointState(self._robot, j, float(v), physicsClientId=cid)
            st = pb.getLinkState(self._robot, self._flange, computeForwardKinematics=True, physicsClientId=cid)
            out[k, :3, :3] = np.asarray(pb.getMatrixFromQuaternion(st[5], physicsClientId=cid)).reshape(3, 3)
            out[k, :3, 3] = st[4]
        return out

    def sphere_centres(self, q: np.ndarray, tip_offset: np.ndarray) -> np.ndarray:
        """Sphere centres p_WE (M,3) for joint angles q (M,7) and the offset (3,) in the flange frame."""
        X = self.flange_poses(q)
        return X[:, :3, 3] + X[:, :3, :3] @ np.asarray(tip_offset, dtype=float)


def panda_flange_poses(q: np.ndarray) -> np.ndarray:
    """Flange poses X_WF (M,4,4) for joint angles q (M,7) in radians."""
    with PandaModel() as m:
        return m.flange_poses(q)


def panda_joint_limits() -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) limits (7,) in radians of the arm joints, from the same URDF."""
    with PandaModel() as m:
        return m.lower, m.upper


def panda_sphere_centres(q: np.ndarray, tip_offset: np.ndarray) -> np.ndarray:
    """Sphere centres p_WE (M,3) for joint angles q (M,7) and the offset (3,) in the flange frame."""
    with PandaModel() as m:
        return m.sphere_centres(q, tip_offset)
