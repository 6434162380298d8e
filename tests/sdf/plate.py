"""A slab x in [0, t], |y|, |z| <= 3 cm, seen along ±x by two 40×40 cameras 25 cm away: its rays, views and
thickness measure, shared by the tests of the band behind a reading (``trunc_back``)
and of the readings other views saw through (``contradicted_readings``)."""

import numpy as np

from service.sdf import RaySet, SdfConfig, fit_sdf, rays_from_frame, sdf_query
from service.transforms import X_inv, make_X

H, W = 40, 40
K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])
BOUNDS_O = np.array([[-0.03, -0.04, -0.04], [0.034, 0.04, 0.04]])


def plate_views(t, sides=(0, 1), background=0.5):
    """Rays and views (K, X_CO, depth) of the slab of thickness ``t``; ``background`` is the depth (m) of the
    pixels off the slab (0: no reading)."""
    parts, views = [], []
    for k, (cx, sgn) in enumerate(((-0.25, 1.0), (0.25 + t, -1.0))):
        if k not in sides:
            continue
        z = np.array([sgn, 0.0, 0.0])
        x = np.array([0.0, sgn, 0.0])
        X_OC = make_X(np.stack([x, np.cross(z, x), z], 1), np.array([cx, 0.0, 0.0]))
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        d = np.stack([u, v, np.ones_like(u)], -1, dtype=float) @ np.linalg.inv(K).T @ X_OC[:3, :3].T  # camera-z = 1
        face = 0.0 if sgn > 0 else t
        zc = (face - cx) / d[..., 0]  # camera depth where the ray meets the face
        hit = zc[..., None] * d + np.array([cx, 0.0, 0.0])
        mask = (np.abs(hit[..., 1]) < 0.03) & (np.abs(hit[..., 2]) < 0.03)
        depth = np.where(mask, zc, background).astype(np.float32)
        parts.append(rays_from_frame(depth, mask, K, X_OC, stride=1, ring_px=4, rng=np.random.default_rng(k)))
        views.append((K, X_inv(X_OC), depth))
    return RaySet.concatenate(parts), views


def fit_thickness(rays, **fit_kw):
    """Median thickness (m) of the fitted SDF's inside along x over 20 lines |y|, |z| < 1.5 cm."""
    cfg = SdfConfig(resolution=40, steps=150, rays_per_step=512, samples_near=12, samples_far=6,
                    trunc_back=fit_kw.pop("trunc_back", None))
    g = fit_sdf(rays, cfg, bounds_O=BOUNDS_O, **fit_kw)
    xs = np.linspace(-0.02, 0.024, 441)
    yz = np.random.default_rng(0).uniform(-0.015, 0.015, (20, 2))
    th = [(sdf_query(g, np.stack([xs, np.full_like(xs, y), np.full_like(xs, z)], 1)) < 0).sum() * (xs[1] - xs[0])
          for y, z in yz]
    return float(np.median(th))
