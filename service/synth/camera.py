"""Pinhole camera of the synthetic lab and its mapping onto pybullet's OpenGL-style renderer.

OpenCV intrinsics ``K = [[fx,0,cx],[0,fy,cy],[0,0,1]]`` with pixel centres at integer (u, v).
Camera frame C is OpenCV (x right, y down, z forward); the OpenGL eye frame is
``X_WCgl = X_WC @ diag(1,-1,-1,1)``, and pybullet takes ``inv(X_WCgl)`` as the view matrix.

Projection (clip = P @ [x_gl, y_gl, z_gl, 1]):
    P00 = 2 fx / W,  P02 = 1 - 2 cx / W,  P11 = 2 fy / H,  P12 = 2 (cy + 1) / H - 1,
    P22 = -(f + n) / (f - n),  P23 = -2 f n / (f - n),  P32 = -1.
The half-pixel terms in P02 / P12 account for where pybullet's TinyRenderer samples a pixel (the
window's integer coordinate, rows flipped); they were measured by rendering tilted planes and make
depth(u, v) the depth along the ray ``K^-1 [u, v, 1]`` to well under 0.01 px.

The depth buffer ``d`` in [0, 1] is non-linear; metric depth along the optical axis is
``z = f n / (f - (f - n) d)``; ``d = 1`` (nothing hit) is no reading.
"""

from __future__ import annotations

import numpy as np

# RealSense-like colour intrinsics at 640x480
FX_640 = 615.0
NEAR = 0.05
FAR = 4.0


def intrinsics(width: int, height: int, fx_640: float = FX_640) -> np.ndarray:
    """K (3,3) for a RealSense-like camera at ``width x height`` (focal length scales with width)."""
    f = fx_640 * width / 640.0
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """X_WC (4,4) of an OpenCV camera at ``eye`` looking at ``target`` with world ``up`` pointing up in the image."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, 0], X[:3, 1], X[:3, 2], X[:3, 3] = x, y, z, eye
    return X


def gl_view_matrix(X_WC: np.ndarray) -> list[float]:
    """pybullet view matrix (16 floats, column-major) of the OpenCV camera pose X_WC."""
    V = np.linalg.inv(X_WC @ np.diag([1.0, -1.0, -1.0, 1.0]))
    return V.T.reshape(-1).tolist()


def gl_projection_matrix(K: np.ndarray, width: int, height: int, near: float = NEAR, far: float = FAR) -> list[float]:
    """pybullet projection matrix (16 floats, column-major) reproducing K exactly (see module doc)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * fx / width
    P[0, 2] = 1.0 - 2.0 * cx / width
    P[1, 1] = 2.0 * fy / height
    P[1, 2] = 2.0 * (cy + 1.0) / height - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P.T.reshape(-1).tolist()


def linearize_depth(buf: np.ndarray, near: float = NEAR, far: float = FAR) -> np.ndarray:
    """Non-linear depth buffer (H,W) in [0,1] -> metric z-depth (H,W) float64; 0 where nothing was hit."""
    d = np.asarray(buf, np.float64)
    z = far * near / (far - (far - near) * d)
    z[d >= 1.0 - 1e-7] = 0.0
    return z


def backproject(depth: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Pixels with depth > 0 (and in ``mask``) -> points in C (N,3): ``p_C = z K^-1 [u, v, 1]``."""
    v, u = np.nonzero((depth > 0) if mask is None else (mask & (depth > 0)))
    z = depth[v, u]
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.c_[x, y, z]
