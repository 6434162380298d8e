"""Supervision samples induced by the physible set P = {(p_i, n̂_i)} (Vysics §4.B, method-notes §6.2).

- Support-point ray samples: for each (p, n̂), x = p + l n̂ with target SDF(x) = l,
  l ~ U[−D_in, 0] (N_in of them), U[0, D_out] (N_out), U[0, D_far] (N_far).
- Hyperplane lower-bound samples: around an anchor (v, m̂) (a point of the physible mesh lying on a
  supporting plane of P, with its face normal), in the local frame (m̂, t₁, t₂),
  q = v + h m̂ + r (cos α t₁ + sin α t₂), α ~ U[0, 2π), r = R·U[0,1] (as the authors' code, not
  area-uniform); bound b = h, i.e. SDF(q) ≥ (q − v)·m̂. Three groups: N_in with h ~ U[−H_in, 0],
  r ≤ R_near; N_near with h ~ U[0, H_near], r ≤ R_near; N_far with h ~ U[0, H_far], r ≤ R_far.
- Anchors: ``n_surface`` area-weighted samples x (face normal m̂) of the physible mesh, kept when
  min_i |(x − p_i)·n̂_i| < tol and m̂·n̂_{i*} > 0 for the nearest plane i* (authors' extra filter).
- Convexity pairs: s₁ from the visible near-surface points, s₂ from the ray samples (target l₂),
  t ~ U[0,1]; the point t s₁ + (1 − t) s₂ is formed in the loss.

All arrays are float64 numpy, frame O, metres. Functions are pure given their ``rng``.
"""

from __future__ import annotations

import numpy as np

from service.fusion.types import SampleExtents
from service.mesh import Mesh


def _check_pn(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(points, float).reshape(-1, 3)
    N = np.asarray(normals, float).reshape(-1, 3)
    if P.shape != N.shape:
        raise ValueError(f"points {P.shape} and normals {N.shape} must have the same shape (P,3)")
    nrm = np.linalg.norm(N, axis=1, keepdims=True)
    if np.any(nrm < 1e-9):
        raise ValueError("normals must be non-zero")
    return P, N / nrm


def ray_samples(
    points: np.ndarray, normals: np.ndarray, ext: SampleExtents, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Support-point ray samples. points, normals (P,3) -> x (M,3), l (M,) with M = P·(N_in+N_out+N_far)."""
    P, N = _check_pn(points, normals)
    n = len(P)
    l_in = -ext.ray_d_in * rng.random((n, ext.ray_n_in))
    l_out = ext.ray_d_out * rng.random((n, ext.ray_n_out))
    l_far = ext.ray_d_far * rng.random((n, ext.ray_n_far))
    lv = np.concatenate([l_in, l_out, l_far], 1)  # (P,k)
    x = P[:, None, :] + lv[..., None] * N[:, None, :]
    return x.reshape(-1, 3), lv.reshape(-1)


def tangent_frames(normals: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two random unit tangents (P,3), (P,3) orthonormal to each unit normal (P,3)."""
    N = np.asarray(normals, float)
    a = rng.normal(size=N.shape)
    t1 = a - (a * N).sum(1, keepdims=True) * N
    bad = np.linalg.norm(t1, axis=1) < 1e-6
    if np.any(bad):  # random vector parallel to the normal: use a fixed axis
        alt = np.where(np.abs(N[bad, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        t1[bad] = alt - (alt * N[bad]).sum(1, keepdims=True) * N[bad]
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(N, t1)
    return t1, t2


def hyperplane_samples(
    anchors: np.ndarray, normals: np.ndarray, ext: SampleExtents, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder samples around anchors (A,3) with normals (A,3) -> q (M,3), lower bounds b (M,)."""
    V, M = _check_pn(anchors, normals)
    n = len(V)
    t1, t2 = tangent_frames(M, rng)
    groups = [
        (ext.hc_n_in, -ext.hc_h_in, 0.0, ext.hc_r_near),
        (ext.hc_n_near, 0.0, ext.hc_h_near, ext.hc_r_near),
        (ext.hc_n_far, 0.0, ext.hc_h_far, ext.hc_r_far),
    ]
    hs, rs = [], []
    for k, h0, h1, R in groups:
        hs.append(h0 + (h1 - h0) * rng.random((n, k)))
        rs.append(R * rng.random((n, k)))
    h = np.concatenate(hs, 1)
    r = np.concatenate(rs, 1)
    alpha = 2 * np.pi * rng.random(h.shape)
    q = (
        V[:, None, :]
        + h[..., None] * M[:, None, :]
        + (r * np.cos(alpha))[..., None] * t1[:, None, :]
        + (r * np.sin(alpha))[..., None] * t2[:, None, :]
    )
    return q.reshape(-1, 3), h.reshape(-1)


def hyperplane_anchors(
    mesh: Mesh,
    points: np.ndarray,
    normals: np.ndarray,
    rng: np.random.Generator,
    n_surface: int = 25_000,
    tol: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray]:
    """Points (A,3) of ``mesh`` within ``tol`` of a supporting plane of P, with face normals (A,3)."""
    P, N = _check_pn(points, normals)
    if len(P) == 0 or mesh.is_empty:
        return np.zeros((0, 3)), np.zeros((0, 3))
    tm = mesh.to_trimesh()
    area = np.asarray(tm.area_faces, float)
    if area.sum() <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    face = rng.choice(len(area), size=n_surface, p=area / area.sum())
    tri = np.asarray(tm.triangles, float)[face]  # (S,3,3)
    u, v = rng.random(n_surface), rng.random(n_surface)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    x = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    m = np.asarray(tm.face_normals, float)[face]
    keep = np.zeros(n_surface, bool)
    offs = (P * N).sum(1)
    chunk = max(1, 4_000_000 // len(P))  # (chunk, P) plane distances, ≤ 32 MB at a time
    for a in range(0, n_surface, chunk):
        xs, ms = x[a:a + chunk], m[a:a + chunk]
        d = np.abs(xs @ N.T - offs[None, :])
        i_star = d.argmin(1)
        keep[a:a + chunk] = (d[np.arange(len(xs)), i_star] < tol) & ((ms * N[i_star]).sum(1) > 0)
    return x[keep], m[keep]


def inside_box(x: np.ndarray, bounds_O: np.ndarray) -> np.ndarray:
    """(M,) bool: rows of x (M,3) inside the box bounds_O (2,3)."""
    return np.all((x >= bounds_O[0]) & (x <= bounds_O[1]), axis=1)
