"""Rigid transforms, rotations and quaternions (numpy).

Conventions (docs/conventions.md):
- ``X_AB`` is the 4x4 homogeneous pose of frame B in frame A, column vectors: ``p_A = X_AB @ p_B``.
- Quaternions are unit, scalar first ``[w, x, y, z]``, Hamilton product, and rotate body -> world.
- ``so3_exp`` / ``so3_log`` map rotation vectors (axis * angle, rad) to matrices and back.

All functions accept a leading batch shape ``(..., )`` unless stated otherwise.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def skew(v: np.ndarray) -> np.ndarray:
    """(…,3) -> (…,3,3) cross-product matrix, ``skew(a) @ b == a × b``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def so3_exp(r: np.ndarray) -> np.ndarray:
    """Rotation vector (…,3) -> rotation matrix (…,3,3) (Rodrigues)."""
    r = np.asarray(r, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def horizontal_turn(a: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """The least rotation that makes the unit vector ``a`` (3,) (in W) horizontal: (v, s, θ) with v = a × h (h the
    unit horizontal direction of a), s = |v| = sin θ and θ (rad) the angle from a to h, so the rotation is about
    v / s by θ (none needed when s is 0). None when a is vertical (no horizontal direction of its own)."""
    h = np.array([a[0], a[1], 0.0])
    if np.linalg.norm(h) < 1e-9:
        return None
    h /= np.linalg.norm(h)
    v = np.cross(a, h)
    s = float(np.linalg.norm(v))
    return v, s, float(np.arctan2(s, a @ h))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (…,3,3) -> rotation vector (…,3), angle in [0, π]."""
    return quat_to_rotvec(mat_to_quat(R))


def _se3_V(w: np.ndarray) -> np.ndarray:
    """(3,3) left Jacobian of SO(3) at the rotation vector w: the translation part of Exp([w, u]) is V(w) u."""
    th = float(np.linalg.norm(w))
    W = skew(w)
    if th < 1e-8:
        return np.eye(3) + 0.5 * W
    return np.eye(3) + (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * W @ W


def se3_exp(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(4,4) Exp([w, u]) on SE(3): rotation so3_exp(w), translation V(w) u (a screw motion)."""
    return make_X(so3_exp(w), _se3_V(w) @ u)


def se3_log(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(w, u) (3,), (3,) with X = se3_exp(w, u) (rotation vector w, translation part u = V⁻¹ t)."""
    w = so3_log(X[:3, :3])
    return w, np.linalg.inv(_se3_V(w)) @ X[:3, 3]


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad) of rotation matrices (…,3,3)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def quat_normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), _EPS)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """Choose the sign with w >= 0 (q and -q are the same rotation)."""
    q = quat_normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def quat_make_continuous(q: np.ndarray) -> np.ndarray:
    """(N,4) sequence with signs flipped so consecutive quaternions have a positive dot product."""
    q = quat_normalize(np.array(q, dtype=float))
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    return q


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b for (…,4) wxyz quaternions."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """wxyz (…,4) -> rotation matrix (…,3,3)."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (…,3,3) -> wxyz (…,4) with w >= 0 (Shepperd's method, batched)."""
    R = np.asarray(R, dtype=float)
    shp = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], -1)
    choice = np.argmax(np.concatenate([tr[:, None], diag], -1), -1)
    q = np.empty((len(R), 4))
    # case trace
    s = np.sqrt(np.maximum(1.0 + tr, _EPS)) * 2
    qt = np.stack([0.25 * s, (R[:, 2, 1] - R[:, 1, 2]) / s, (R[:, 0, 2] - R[:, 2, 0]) / s, (R[:, 1, 0] - R[:, 0, 1]) / s], -1)
    s0 = np.sqrt(np.maximum(1.0 + R[:, 0, 0] - R[:, 1, 1] - R[:, 2, 2], _EPS)) * 2
    q0 = np.stack([(R[:, 2, 1] - R[:, 1, 2]) / s0, 0.25 * s0, (R[:, 0, 1] + R[:, 1, 0]) / s0, (R[:, 0, 2] + R[:, 2, 0]) / s0], -1)
    s1 = np.sqrt(np.maximum(1.0 + R[:, 1, 1] - R[:, 0, 0] - R[:, 2, 2], _EPS)) * 2
    q1 = np.stack([(R[:, 0, 2] - R[:, 2, 0]) / s1, (R[:, 0, 1] + R[:, 1, 0]) / s1, 0.25 * s1, (R[:, 1, 2] + R[:, 2, 1]) / s1], -1)
    s2 = np.sqrt(np.maximum(1.0 + R[:, 2, 2] - R[:, 0, 0] - R[:, 1, 1], _EPS)) * 2
    q2 = np.stack([(R[:, 1, 0] - R[:, 0, 1]) / s2, (R[:, 0, 2] + R[:, 2, 0]) / s2, (R[:, 1, 2] + R[:, 2, 1]) / s2, 0.25 * s2], -1)
    for k, qk in enumerate((qt, q0, q1, q2)):
        m = choice == k
        q[m] = qk[m]
    return quat_canonical(q).reshape(*shp, 4)


def quat_to_xyzw(q: np.ndarray) -> list[float]:
    """wxyz (4,) -> ``[x, y, z, w]`` floats (pybullet's order)."""
    return [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


def quat_from_xyzw(q_xyzw) -> np.ndarray:
    """pybullet's ``[x, y, z, w]`` (4,) -> wxyz (4,) float array."""
    return np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]], float)


def pose_from_xyzw(pos, orn_xyzw) -> np.ndarray:
    """Pose (4,4) from a position (3,) and a pybullet ``[x, y, z, w]`` orientation (e.g. a body's base frame in W
    from ``getBasePositionAndOrientation``)."""
    return make_X(quat_to_mat(quat_from_xyzw(orn_xyzw)), np.asarray(pos, float))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """wxyz (…,4) -> rotation vector (…,3), angle in [0, π]."""
    q = quat_canonical(q)
    w = np.clip(q[..., 0], -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    scale = np.where(s < 1e-10, 2.0, angle / np.maximum(s, 1e-300))
    return v * scale[..., None]


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    r = np.asarray(r, float)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * theta
    k = np.where(theta < 1e-10, 0.5, np.sin(half) / np.maximum(theta, 1e-300))
    return np.concatenate([np.cos(half), r * k], -1)


def make_X(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Rotation (…,3,3) and translation (…,3) -> pose (…,4,4)."""
    R = np.asarray(R, float)
    p = np.asarray(p, float)
    X = np.zeros(R.shape[:-2] + (4, 4))
    X[..., :3, :3] = R
    X[..., :3, 3] = p
    X[..., 3, 3] = 1.0
    return X


def X_inv(X: np.ndarray) -> np.ndarray:
    """Inverse of rigid poses (…,4,4)."""
    R = X[..., :3, :3]
    p = X[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_X(Rt, -(Rt @ p[..., None])[..., 0])


def transform_points(X: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply one pose (4,4) to points (N,3)."""
    return p @ X[:3, :3].T + X[:3, 3]


def project_to_pixels(P_C: np.ndarray, K: np.ndarray, shape: tuple[int, ...], z_min: float = 1e-6
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinhole projection of camera-frame points (N,3) with intrinsics K (3,3): the nearest pixel column u and row
    v (N,) int64, and (N,) bool ``inside``: in front of the camera (z > ``z_min``) and within an image of
    ``shape`` (H, W, …). u, v of points not in front are meaningless."""
    P_C = np.asarray(P_C, float)
    z = P_C[:, 2]
    front = z > z_min
    zz = np.where(front, z, 1.0)
    u = np.round(K[0, 0] * P_C[:, 0] / zz + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * P_C[:, 1] / zz + K[1, 2]).astype(np.int64)
    inside = front & (u >= 0) & (u < shape[1]) & (v >= 0) & (v < shape[0])
    return u, v, inside


def pose_to_xyzquat(X: np.ndarray) -> np.ndarray:
    """(…,4,4) -> (…,7) ``x,y,z,qw,qx,qy,qz`` (the trajectory.csv / poses.csv layout)."""
    return np.concatenate([X[..., :3, 3], mat_to_quat(X[..., :3, :3])], -1)


def xyzquat_to_pose(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return make_X(quat_to_mat(v[..., 3:7]), v[..., :3])


def pose_distance(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Distance between two poses (4,4): translation (m) and rotation angle (degrees) of A⁻¹B."""
    dR = A[:3, :3].T @ B[:3, :3]
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), float(np.degrees(rotation_angle(dR)))


def pose_errors(X_est: np.ndarray, X_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose translation error (m) and geodesic rotation error (rad) between (N,4,4) stacks."""
    dt = np.linalg.norm(X_est[..., :3, 3] - X_ref[..., :3, 3], axis=-1)
    dR = np.swapaxes(X_ref[..., :3, :3], -1, -2) @ X_est[..., :3, :3]
    return dt, rotation_angle(dR)
