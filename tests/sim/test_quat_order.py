"""pybullet's quaternion order ``[x, y, z, w]`` and the converters of ``service.transforms`` (``quat_to_xyzw``,
``quat_from_xyzw``, ``pose_from_xyzw``) that the simulator, the synthetic lab and the URDF export share."""

import numpy as np
import pybullet as pb

from service.transforms import mat_to_quat, pose_from_xyzw, quat_from_xyzw, quat_to_mat, quat_to_xyzw, so3_exp


def test_converters_match_pybullets_order():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = so3_exp(rng.normal(size=3))
        q = mat_to_quat(R)  # wxyz
        xyzw = quat_to_xyzw(q)
        assert all(type(v) is float for v in xyzw)
        assert np.allclose(np.array(pb.getMatrixFromQuaternion(xyzw)).reshape(3, 3), R, atol=1e-12)
        assert np.array_equal(quat_from_xyzw(xyzw), q)
        p = rng.normal(size=3)
        X = pose_from_xyzw(tuple(p), tuple(xyzw))
        assert np.array_equal(X[:3, 3], p) and np.array_equal(X[:3, :3], quat_to_mat(q))
        assert np.array_equal(X[3], [0.0, 0.0, 0.0, 1.0])
