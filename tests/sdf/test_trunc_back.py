"""The band behind the observed surface (``SdfConfig.trunc_back``): a plate thinner than the truncation τ,
seen from both sides. With BundleSDF's symmetric band every reading also claims the τ behind it as inside, which
reaches through the plate into the air on the other side and thickens it; a shallow band keeps its thickness."""

import numpy as np
import pytest

from service.sdf import RaySet, SdfConfig, fit_sdf, rays_from_frame, sdf_query
from service.transforms import make_X

T = 0.004  # plate x in [0, T], |y|, |z| <= 3 cm


def _plate_rays():
    H, W = 40, 40
    K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])
    parts = []
    for k, (cx, sgn) in enumerate(((-0.25, 1.0), (0.25 + T, -1.0))):
        z = np.array([sgn, 0.0, 0.0])
        x = np.array([0.0, sgn, 0.0])
        X_OC = make_X(np.stack([x, np.cross(z, x), z], 1), np.array([cx, 0.0, 0.0]))
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        d = np.stack([u, v, np.ones_like(u)], -1, dtype=float) @ np.linalg.inv(K).T @ X_OC[:3, :3].T  # camera-z = 1
        face = 0.0 if sgn > 0 else T
        zc = (face - cx) / d[..., 0]  # camera depth where the ray meets the face
        hit = zc[..., None] * d + np.array([cx, 0.0, 0.0])
        mask = (np.abs(hit[..., 1]) < 0.03) & (np.abs(hit[..., 2]) < 0.03)
        depth = np.where(mask, zc, 0.0).astype(np.float32)
        parts.append(rays_from_frame(depth, mask, K, X_OC, stride=1, ring_px=4, rng=np.random.default_rng(k)))
    return RaySet.concatenate(parts)


def _thickness(back):
    cfg = SdfConfig(resolution=40, steps=150, rays_per_step=512, samples_near=12, samples_far=6, trunc_back=back)
    g = fit_sdf(_plate_rays(), cfg, bounds_O=np.array([[-0.03, -0.04, -0.04], [0.034, 0.04, 0.04]]))
    xs = np.linspace(-0.02, 0.024, 441)
    yz = np.random.default_rng(0).uniform(-0.015, 0.015, (20, 2))
    th = []
    for y, z in yz:
        s = sdf_query(g, np.stack([xs, np.full_like(xs, y), np.full_like(xs, z)], 1))
        th.append((s < 0).sum() * (xs[1] - xs[0]))
    return float(np.median(th))


def test_shallow_band_keeps_a_thin_plate_thin():
    thick_sym = _thickness(None)
    thick_back = _thickness(0.002)
    assert abs(thick_back - T) < 0.0015, thick_back
    assert thick_sym > thick_back + 0.002, (thick_sym, thick_back)


def test_trunc_back_is_validated():
    with pytest.raises(ValueError, match="trunc_back"):
        SdfConfig(trunc_back=0.02)
    with pytest.raises(ValueError, match="trunc_back"):
        SdfConfig(trunc_back=0.0)
