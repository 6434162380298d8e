"""Velocities from tracked poses (method-notes §1.3, as the authors' conversion script does).

1. Rotation vectors of sign-continuous quaternions and positions are median-filtered (kernel 3, edges
   repeated).
2. Backward differences with the real timestamps: v_k = (p_k − p_{k−1}) / (t_k − t_{k−1}) (in W),
   ω_k = Log(R_{k−1}ᵀ R_k) / (t_k − t_{k−1}) (body axes); the first row copies the second.
3. Both velocities are median-filtered again (kernel 3).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from service.transforms import mat_to_quat, quat_make_continuous, quat_to_mat, quat_to_rotvec, rotvec_to_quat, so3_log


def _medfilt(x: np.ndarray, k: int) -> np.ndarray:
    if k <= 1 or len(x) < 2:
        return x.copy()
    return median_filter(x, size=(k, 1), mode="nearest")


def filter_poses(X_WO: np.ndarray, kernel: int = 3) -> np.ndarray:
    """Median-filtered poses (N,4,4): rotation vectors of continuous quaternions and positions, per component."""
    q = quat_make_continuous(mat_to_quat(X_WO[:, :3, :3]))
    # rotation vectors continuous around the median: express relative to the first orientation
    r = quat_to_rotvec(q)
    # keep rotvecs continuous where the angle passes π: unwrap by choosing the equivalent closest to the previous
    for i in range(1, len(r)):
        th = np.linalg.norm(r[i])
        if th > 1e-9:
            alt = r[i] * (1 - 2 * np.pi / th)
            if np.linalg.norm(alt - r[i - 1]) < np.linalg.norm(r[i] - r[i - 1]):
                r[i] = alt
    rf = _medfilt(r, kernel)
    pf = _medfilt(X_WO[:, :3, 3], kernel)
    out = np.tile(np.eye(4), (len(X_WO), 1, 1))
    out[:, :3, :3] = quat_to_mat(rotvec_to_quat(rf))
    out[:, :3, 3] = pf
    return out


def velocities(t: np.ndarray, X_WO: np.ndarray, kernel: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(v_WO_W (N,3), w_WO_O (N,3)) from poses (N,4,4) at times t (N,) by filtered backward differences."""
    t = np.asarray(t, float)
    N = len(t)
    if N < 2:
        return np.zeros((N, 3)), np.zeros((N, 3))
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError("frame times must increase strictly")
    Xf = filter_poses(X_WO, kernel)
    v = np.zeros((N, 3))
    w = np.zeros((N, 3))
    v[1:] = (Xf[1:, :3, 3] - Xf[:-1, :3, 3]) / dt[:, None]
    dR = np.swapaxes(Xf[:-1, :3, :3], -1, -2) @ Xf[1:, :3, :3]
    w[1:] = so3_log(dR) / dt[:, None]
    v[0], w[0] = v[1], w[1]
    return _medfilt(v, kernel), _medfilt(w, kernel)
