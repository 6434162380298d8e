"""Convex geometry as a deep support function, its mesh, and closest points on its hull.

Deep support function (HomogeneousICNN; Halm et al. 2023, PLL ``deep_support_function.py``):
    h₁ = σ(A₁ᵀ d),  h₂ = σ(A₂ᵀ d + |H₂|ᵀ h₁),  f(d) = |w|ᵀ h₂,   σ = LeakyReLU(0.5), no biases.
σ is convex, non-decreasing and positively homogeneous, hidden-path weights are non-negative, so f is
convex and positively homogeneous of degree one: the support function h_S(d) = max_{s∈S} s·d of a
convex body S. The support point is its gradient s(d) = ∇f(d), computed analytically (manual
back-propagation with σ'(a) ∈ {1, 0.5}); it is differentiable in the weights and degree-0 homogeneous.

Init (PLL): A_i ~ kaiming-uniform bound sqrt(6/W) (A₂ × 1/√2), H₂ ~ U(±2 sqrt(2/(1+0.25))/W),
w ~ U(±L·2 sqrt(2/(W(1+0.25)))) with L a length scale (half the bounding-box diagonal of a guess).
Optionally the network is pre-fitted to the support points of a guess (PLL ``train_icnn.py``).

Mesh export (§3.4): directions on the surface of a k×k×k cube grid (k = 8 → 296), normalised,
support points, convex hull (scipy Qhull), faces oriented outward.

Polytope option (ContactNets / PLL ``Polygon``, §3.5): learnable vertices V, s(d) = argmax_v d·v.

Closest point on a triangle mesh: exact point-triangle closest points (Ericson, Real-Time Collision
Detection §5.1.5) vectorised over points × triangles; the sign of the distance to a convex hull is
positive when the point lies outside some face plane.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from service.mesh import Mesh

NEG_SLOPE = 0.5


def cube_surface_directions(k: int = 8) -> np.ndarray:
    """Unit directions through the surface points of a k×k×k grid on [−1,1]³, (k³−(k−2)³, 3)."""
    g = np.linspace(-1.0, 1.0, k)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    P = np.stack([X, Y, Z], -1).reshape(-1, 3)
    P = P[np.abs(P).max(-1) >= 1.0 - 1e-12]
    return P / np.linalg.norm(P, axis=-1, keepdims=True)


def fibonacci_directions(n: int) -> np.ndarray:
    """(n,3) nearly uniform unit directions."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = math.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)


class HomogeneousICNN(nn.Module):
    """Deep support function of depth 2 (see module docstring). ``forward(d)`` returns s(d) (…,3)."""

    def __init__(self, width: int = 64, length_scale: float = 0.1, generator: torch.Generator | None = None):
        super().__init__()
        W = width
        b_a = math.sqrt(6.0 / W)
        a_h = 2.0 * math.sqrt(2.0 / (1.0 + NEG_SLOPE**2)) / W
        b_w = length_scale * 2.0 * math.sqrt(2.0 / (W * (1.0 + NEG_SLOPE**2)))

        def U(shape, b):
            return (torch.rand(shape, dtype=torch.float64, generator=generator) * 2.0 - 1.0) * b

        self.A1 = nn.Parameter(U((3, W), b_a))
        self.A2 = nn.Parameter(U((3, W), b_a) / math.sqrt(2.0))
        self.H2 = nn.Parameter(U((W, W), a_h))
        self.w = nn.Parameter(U((W,), b_w))

    def _pre(self, d: torch.Tensor):
        a1 = d @ self.A1
        h1 = torch.nn.functional.leaky_relu(a1, NEG_SLOPE)
        H = self.H2.abs()
        a2 = d @ self.A2 + h1 @ H
        return a1, a2, H

    def support_value(self, d: torch.Tensor) -> torch.Tensor:
        """f(d) (…,) — the support function value."""
        _, a2, _ = self._pre(d)
        return torch.nn.functional.leaky_relu(a2, NEG_SLOPE) @ self.w.abs()

    def forward(self, d: torch.Tensor) -> torch.Tensor:
        """Support point s(d) = ∇f(d), (…,3)."""
        a1, a2, H = self._pre(d)
        one = torch.ones((), dtype=d.dtype)
        half = torch.full((), NEG_SLOPE, dtype=d.dtype)
        g2 = torch.where(a2 > 0, one, half) * self.w.abs()
        g1 = (g2 @ H.T) * torch.where(a1 > 0, one, half)
        return g1 @ self.A1.T + g2 @ self.A2.T


class PolytopeSupport(nn.Module):
    """Convex polytope given by learnable vertices V (N,3) (ContactNets / PLL ``Polygon``, method-notes §3.5):
    s(d) = V[argmax_v d·v], f(d) = max_v d·v. A contact moves only the vertex that is the support point of its
    query direction, so corners and faces are learned independently (the deep support function couples them
    through shared weights). Vertices that end inside the hull are ignored by the mesh export."""

    def __init__(self, vertices: np.ndarray):
        super().__init__()
        self.V = nn.Parameter(torch.as_tensor(np.asarray(vertices, float), dtype=torch.float64))

    def forward(self, d: torch.Tensor) -> torch.Tensor:
        return self.V[torch.argmax(d @ self.V.T, -1)]

    def support_value(self, d: torch.Tensor) -> torch.Tensor:
        return (d @ self.V.T).max(-1).values


def hull_mesh(points: np.ndarray) -> Mesh:
    """Convex hull of points (N,3) as a Mesh with outward (counter-clockwise) faces."""
    from scipy.spatial import ConvexHull

    pts = np.unique(np.round(np.asarray(points, float), 12), axis=0)
    hull = ConvexHull(pts)
    used = np.unique(hull.simplices)
    remap = -np.ones(len(pts), np.int64)
    remap[used] = np.arange(len(used))
    V = pts[used]
    F = remap[hull.simplices]
    # orient outward using the hull's facet normals
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    flip = (n * hull.equations[:, :3]).sum(-1) < 0
    F[flip] = F[flip][:, [0, 2, 1]]
    return Mesh(V, F.astype(np.int64))


@torch.no_grad()
def export_mesh(net: nn.Module, directions: np.ndarray) -> tuple[Mesh, np.ndarray]:
    """Convex hull of the support points of ``directions`` (D,3). Returns (mesh, support points (D,3))."""
    d = torch.as_tensor(directions, dtype=torch.float64)
    s = net(d).numpy()
    return hull_mesh(s), s


def closest_point_on_triangles(p: np.ndarray, tri: np.ndarray, chunk: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """Exact closest points of p (N,3) on the union of triangles tri (F,3,3). Returns (points (N,3), dist (N,))."""
    p = np.asarray(p, float)
    out = np.empty_like(p)
    dist = np.empty(len(p))
    A, B, C = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = B - A, C - A
    for s in range(0, len(p), max(1, chunk)):
        q = p[s : s + chunk, None, :]  # (n,1,3)
        ap = q - A
        d1 = (ab * ap).sum(-1)
        d2 = (ac * ap).sum(-1)
        bp = q - B
        d3 = (ab * bp).sum(-1)
        d4 = (ac * bp).sum(-1)
        cp = q - C
        d5 = (ab * cp).sum(-1)
        d6 = (ac * cp).sum(-1)
        va = d3 * d6 - d5 * d4
        vb = d5 * d2 - d1 * d6
        vc = d1 * d4 - d3 * d2
        denom = va + vb + vc
        denom = np.where(np.abs(denom) < 1e-300, 1e-300, denom)
        v = vb / denom
        w = vc / denom
        res = A + ab * v[..., None] + ac * w[..., None]  # interior
        # edge BC
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        wbc = (d4 - d3) / np.where((d4 - d3) + (d5 - d6) == 0, 1e-300, (d4 - d3) + (d5 - d6))
        res = np.where(m[..., None], B + (C - B) * wbc[..., None], res)
        # edge AC
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        wac = d2 / np.where(d2 - d6 == 0, 1e-300, d2 - d6)
        res = np.where(m[..., None], A + ac * wac[..., None], res)
        # edge AB
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        vab = d1 / np.where(d1 - d3 == 0, 1e-300, d1 - d3)
        res = np.where(m[..., None], A + ab * vab[..., None], res)
        # vertices
        res = np.where(((d6 >= 0) & (d5 <= d6))[..., None], C + 0 * res, res)
        res = np.where(((d3 >= 0) & (d4 <= d3))[..., None], B + 0 * res, res)
        res = np.where(((d1 <= 0) & (d2 <= 0))[..., None], A + 0 * res, res)
        dd = ((res - q) ** 2).sum(-1)
        j = dd.argmin(-1)
        idx = np.arange(len(j))
        out[s : s + chunk] = res[idx, j]
        dist[s : s + chunk] = np.sqrt(dd[idx, j])
    return out, dist


def closest_point_on_hull(mesh: Mesh, p: np.ndarray, candidates: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Closest surface points (N,3) of a convex mesh and signed distances (N,) (positive outside).

    ``candidates`` = k > 0: points outside are tested only against the k faces with the largest plane
    distance (the faces the point sees most directly; the closest point lies on a face the point sees);
    points inside are projected exactly onto their nearest face plane (for a convex body that projection lies
    on the face). Exact for points near the surface, k× fewer point-triangle tests; 0 = all faces (exact)."""
    V = np.asarray(mesh.vertices, float)
    F = np.asarray(mesh.faces, np.int64)
    p = np.asarray(p, float)
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
    off = (n * tri[:, 0]).sum(-1)
    pd = p @ n.T - off  # (N,F) plane distances
    outside = (pd > 1e-12).any(-1)
    if candidates <= 0 or candidates >= len(F):
        cp, dist = closest_point_on_triangles(p, tri)
        return cp, np.where(outside, dist, -dist)
    cp = np.empty_like(p)
    dist = np.empty(len(p))
    ins = ~outside
    if ins.any():
        j = pd[ins].argmax(-1)
        d = pd[ins][np.arange(len(j)), j]
        cp[ins] = p[ins] - d[:, None] * n[j]
        dist[ins] = d
    if outside.any():
        po = p[outside]
        k = np.argpartition(-pd[outside], candidates - 1, axis=-1)[:, :candidates]  # (No,k)
        c, dd = _closest_on_candidates(po, tri, k)
        cp[outside] = c
        dist[outside] = dd
    return cp, dist


def _closest_on_candidates(p: np.ndarray, tri: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of p (N,3) on the triangles tri[k[i]] (k (N,K) face indices per point)."""
    T = tri[k]  # (N,K,3,3)
    A, B, C = T[:, :, 0], T[:, :, 1], T[:, :, 2]
    q = p[:, None, :]
    ab, ac = B - A, C - A
    ap, bp, cpv = q - A, q - B, q - C
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    d5, d6 = (ab * cpv).sum(-1), (ac * cpv).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    denom = np.where(np.abs(denom) < 1e-300, 1e-300, denom)
    res = A + ab * (vb / denom)[..., None] + ac * (vc / denom)[..., None]
    m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    wbc = (d4 - d3) / np.where((d4 - d3) + (d5 - d6) == 0, 1e-300, (d4 - d3) + (d5 - d6))
    res = np.where(m[..., None], B + (C - B) * wbc[..., None], res)
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    res = np.where(m[..., None], A + ac * (d2 / np.where(d2 - d6 == 0, 1e-300, d2 - d6))[..., None], res)
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    res = np.where(m[..., None], A + ab * (d1 / np.where(d1 - d3 == 0, 1e-300, d1 - d3))[..., None], res)
    res = np.where(((d6 >= 0) & (d5 <= d6))[..., None], C, res)
    res = np.where(((d3 >= 0) & (d4 <= d3))[..., None], B, res)
    res = np.where(((d1 <= 0) & (d2 <= 0))[..., None], A, res)
    dd = ((res - q) ** 2).sum(-1)
    j = dd.argmin(-1)
    i = np.arange(len(j))
    return res[i, j], np.sqrt(dd[i, j])


def outward_directions_to(mesh: Mesh, p: np.ndarray, candidates: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points p (N,3): closest hull points, signed distances, and the unit outward normal direction
    n̂ = (p − p')/‖·‖ outside, (p' − p)/‖·‖ inside. Degenerate (on-surface) points get the nearest
    face normal. ``candidates``: see ``closest_point_on_hull``."""
    cp, sd = closest_point_on_hull(mesh, p, candidates)
    diff = np.where((sd >= 0)[:, None], p - cp, cp - p)
    nrm = np.linalg.norm(diff, axis=-1)
    bad = nrm < 1e-9
    if bad.any():
        V = np.asarray(mesh.vertices, float)
        tri = V[np.asarray(mesh.faces, np.int64)]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn = fn / np.maximum(np.linalg.norm(fn, axis=-1, keepdims=True), 1e-300)
        off = (fn * tri[:, 0]).sum(-1)
        k = np.argmax(p[bad] @ fn.T - off, -1)
        diff[bad] = fn[k]
        nrm[bad] = 1.0
    return cp, sd, diff / nrm[:, None]


def pretrain_to_points(net: HomogeneousICNN, vertices: np.ndarray, *, steps: int = 300, n_dirs: int = 1000,
                       lr: float = 5e-3, generator: torch.Generator | None = None) -> float:
    """Fit the network to the convex hull of ``vertices`` (V,3): min mean ‖s(d) − argmax_v d·v‖ + |f(d) − max d·v|.
    Returns the final mean support-value error (m)."""
    V = torch.as_tensor(np.asarray(vertices, float), dtype=torch.float64)
    d = torch.as_tensor(fibonacci_directions(n_dirs), dtype=torch.float64)
    dots = d @ V.T
    tgt_val = dots.max(-1).values
    tgt_pt = V[dots.argmax(-1)]
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    err = float("nan")
    for _ in range(steps):
        opt.zero_grad()
        s = net(d)
        val = (s * d).sum(-1)
        loss = (val - tgt_val).abs().mean() + 0.1 * (s - tgt_pt).norm(dim=-1).mean()
        loss.backward()
        opt.step()
        err = float((val - tgt_val).abs().mean().detach())
    return err
