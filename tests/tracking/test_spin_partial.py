"""Bodies of revolution seen in part (service.tracking.spin.partial_tau): a model covering an 85 mm band of a bottle
(cylinder and domed shoulder) seen from one side, with normals as noisy as the tracker's merged models, fails the
λ̂ test (which scales a rotation by the model's extent) while the same surface covered over 130 mm passes it; the
arc-normalised test admits the band with its axis, and refuses a box seen on three faces."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking import TrackingConfig
from service.tracking.spin import arc_score, find_axis, partial_tau, revolution_axis

R, SHOULDER = 0.034, 0.10


def _bottle(h0: float, h1: float, noise_deg: float = 20.0, seed: int = 0, n: int = 1500):
    """Points (n,3) and unit normals of a bottle (axis z, radius R up to SHOULDER, a spherical dome above) between
    heights h0 and h1, seen over ±70° of azimuth, normals perturbed by about ``noise_deg``."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(h0, h1, n)
    f = rng.uniform(-np.radians(70), np.radians(70), n)
    z = np.where(h > SHOULDER, h - SHOULDER, 0.0)
    r = np.sqrt(np.maximum(R**2 - z**2, 1e-8))
    P = np.stack([r * np.cos(f), r * np.sin(f), h], 1)
    N = np.stack([r * np.cos(f), r * np.sin(f), z], 1)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    N += rng.normal(0, np.radians(noise_deg) / np.sqrt(2), N.shape)
    return P, N / np.linalg.norm(N, axis=1, keepdims=True)


def _box(seed: int = 0, n: int = 1500):
    """Three faces (−x, −y, +z) of a 7 × 7 × 20 cm box with normals perturbed by about 20°."""
    rng = np.random.default_rng(seed)
    e = np.array([0.035, 0.035, 0.10])
    P, N = [], []
    for ax, s in ((0, -1), (1, -1), (2, 1)):
        p = rng.uniform(-e, e, (n // 3, 3))
        p[:, ax] = s * e[ax]
        q = np.zeros((n // 3, 3))
        q[:, ax] = s
        P.append(p)
        N.append(q)
    N = np.vstack(N) + rng.normal(0, np.radians(20) / np.sqrt(2), (n, 3))
    return np.vstack(P), N / np.linalg.norm(N, axis=1, keepdims=True)


def test_partial_band_admitted_with_its_axis():
    Q, N = _bottle(0.045, 0.13)
    assert not revolution_axis(Q, N, 0.03, 0.5)[0]  # the λ̂ test refuses the band ...
    tau = partial_tau(Q, N, 0.03, 0.5, 0.08)
    assert tau > 0.03
    ok, _, a, c = find_axis(Q, N, tau, 0.5, "mixed")
    assert ok
    assert np.degrees(np.arccos(abs(a[2]))) < 2.0  # the bottle's axis
    assert np.linalg.norm((c - (c @ a) * a)[:2]) < 0.003  # through the origin
    assert arc_score(Q, N, a, c) < 0.08
    assert partial_tau(Q, N, 0.03, 0.5, 0.0) == 0.03  # off


def test_longer_cover_passes_the_lambda_test_unchanged():
    Q, N = _bottle(0.0, 0.13)  # the same surface and normals, covered over 130 mm
    assert revolution_axis(Q, N, 0.03, 0.5)[0]
    assert partial_tau(Q, N, 0.03, 0.5, 0.08) == 0.03


def test_box_refused():
    Q, N = _box()
    ok, _, a, c = revolution_axis(Q, N, np.inf, 0.5)
    if ok:  # its weakest direction may be a rotation, but the normals are far from its meridian planes
        assert arc_score(Q, N, a, c) > 0.15
    assert partial_tau(Q, N, 0.03, 0.5, 0.08) == 0.03
    assert not find_axis(Q, N, 0.03, 0.5, "mixed")[0]


@pytest.mark.parametrize("bad", [-0.1, 1.0, 2.0])
def test_bad_setting_refused(bad):
    with pytest.raises(ValueError, match="spin_arc_tau"):
        TrackingConfig(spin_arc_tau=bad)
