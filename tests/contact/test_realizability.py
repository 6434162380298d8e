"""Density realizability of the learned inertia: the enclosing ellipsoid and the bound tr(A(Σ + δδᵀ)) ≤ 1."""

import numpy as np
import torch

from service.contact.inertia import RigidBodyInertia, enclosing_ellipsoid, realizability_ratio, solid_box_inertia


def _box_corners(h):
    return np.array([[sx * h[0], sy * h[1], sz * h[2]] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def test_enclosing_ellipsoid_of_a_box_is_the_circumscribed_one():
    h = np.array([0.09, 0.03, 0.05])
    pts = _box_corners(h) + np.array([0.1, -0.2, 0.05])
    e, A = enclosing_ellipsoid(pts)
    np.testing.assert_allclose(e, [0.1, -0.2, 0.05], atol=2e-3)
    semi = 1.0 / np.sqrt(np.linalg.eigvalsh(A))
    np.testing.assert_allclose(np.sort(semi), np.sort(np.sqrt(3) * h), rtol=0.03)
    r = np.einsum("ni,ij,nj->n", pts - e, A, pts - e)
    assert r.max() <= 1.0 + 1e-9  # every point inside


def test_ratio_separates_realizable_from_unrealizable_inertia():
    h = np.array([0.09, 0.03, 0.05])
    m = 0.35
    e, A = (torch.as_tensor(x) for x in enclosing_ellipsoid(_box_corners(h)))
    uniform = RigidBodyInertia(m, np.zeros(3), solid_box_inertia(h, m))
    assert abs(float(realizability_ratio(uniform, e, A).detach()) - 1 / 3) < 0.02  # Σ = diag(h²/3), semi-axes √3 h
    too_large = RigidBodyInertia(m, np.zeros(3), 10 * solid_box_inertia(h, m))
    assert float(realizability_ratio(too_large, e, A).detach()) > 3.0
    off_centre = RigidBodyInertia(m, np.array([0.0, 0.08, 0.0]), solid_box_inertia(h, m))  # CoM outside the box
    assert float(realizability_ratio(off_centre, e, A).detach()) > 1.0


def test_penalty_gradient_pulls_an_unrealizable_inertia_back():
    h = np.array([0.09, 0.03, 0.05])
    m = 0.35
    e, A = (torch.as_tensor(x) for x in enclosing_ellipsoid(_box_corners(h)))
    body = RigidBodyInertia(m, np.array([0.02, 0.0, 0.0]), 10 * solid_box_inertia(h, m))
    opt = torch.optim.Adam([body.com, body.d, body.s], lr=0.05)
    for _ in range(200):
        opt.zero_grad()
        loss = (realizability_ratio(body, e, A) - 1.0).clamp_min(0.0) ** 2
        loss.backward()
        opt.step()
    assert float(realizability_ratio(body, e, A).detach()) < 1.05
    I = body.central_inertia().detach().numpy()
    assert np.all(np.linalg.eigvalsh(I) > 0)


def test_config_refuses_a_negative_realizability_weight_and_an_unknown_geometry():
    import pytest

    from service.contact.types import ContactConfig

    with pytest.raises(ValueError, match="w_realizable"):
        ContactConfig(w_realizable=-1.0)
    with pytest.raises(ValueError, match="geometry"):
        ContactConfig(geometry="sphere")
    assert ContactConfig.tosses().w_realizable == 0.0
