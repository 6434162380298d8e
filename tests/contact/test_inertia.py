"""Log-Cholesky inertia: validity for any parameters, and round trip."""

import numpy as np
import torch

from service.contact.inertia import inertia_from_params, params_from_inertia, solid_box_inertia, solid_hull_inertia
from service.contact.simulate import box_vertices


def test_any_parameters_give_a_physical_inertia():
    g = torch.Generator().manual_seed(0)
    for _ in range(200):
        d = torch.randn(3, generator=g, dtype=torch.float64) * 2
        s = torch.randn(3, generator=g, dtype=torch.float64) * 0.2
        I = inertia_from_params(d, s, torch.tensor(0.7, dtype=torch.float64)).numpy()
        assert np.allclose(I, I.T)
        ev = np.linalg.eigvalsh(I)
        assert ev.min() > 0
        a, b, c = ev
        assert a + b >= c * (1 - 1e-9) and a + c >= b * (1 - 1e-9) and b + c >= a * (1 - 1e-9)


def test_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        h = rng.uniform(0.01, 0.1, 3)
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        I = Q @ solid_box_inertia(h, 0.5) @ Q.T
        d, s = params_from_inertia(I, 0.5)
        I2 = inertia_from_params(torch.tensor(d), torch.tensor(s), torch.tensor(0.5, dtype=torch.float64)).numpy()
        assert np.allclose(I, I2, rtol=1e-9, atol=1e-15)


def test_solid_hull_inertia_of_a_box():
    h = np.array([0.04, 0.03, 0.02])
    com, I = solid_hull_inertia(box_vertices(h) + [0.01, 0, 0], 0.3)
    assert np.allclose(com, [0.01, 0, 0], atol=1e-12)
    assert np.allclose(I, solid_box_inertia(h, 0.3), rtol=1e-9)
