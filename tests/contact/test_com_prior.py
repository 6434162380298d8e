"""CoM prior toward the uniform centroid of the learned hull (``ContactConfig.w_com_centroid``).

The struck box of ``test_strike.py`` (half-extents 40 × 30 × 20 mm, CoM at its centre, true poses) slides flat on
the table. Its geometry is held at the true box (geometry learning rate 0) and its CoM starts 12 mm above the
centre (as the centroid of a visible mesh that misses the box's bottom). Horizontal strikes and table friction leave
the CoM's height unobserved: without a prior Adam walks it 15 mm and more away; with ``w_com_centroid`` it ends at
the box's centroid.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from service.contact.fit import train
from service.contact.inertia import com_centroid_penalty
from service.contact.learn import build_model, make_transitions
from service.contact.types import ContactConfig

from .test_strike import DT, HALF, MU, R_EE, box_points, strike_session


def _learned_com(**kw) -> np.ndarray:
    X, ee, ve = strike_session()
    tr = make_transitions((X,), (ee,), (ve,), 0.0)
    cfg = dataclasses.replace(ContactConfig.fast(), epochs=30, min_epochs=30, lr=0.0, batch_size=20, **kw)
    model = build_model(0.3, MU, 0.15, box_points(HALF, n=6), width=cfg.width, init_radius=cfg.init_radius,
                        pretrain_steps=cfg.pretrain_steps, learn_com=True, learn_friction=False, learn_mass=False,
                        seed=0)
    with torch.no_grad():
        model.inertia.com.copy_(torch.tensor([0.0, 0.0, 0.012], dtype=torch.float64))
    train(model, tr, DT, cfg, ee_radius=R_EE)
    return model.inertia.com.detach().numpy()


def test_com_prior_holds_an_unobserved_com_at_the_centroid():
    free = _learned_com()
    assert np.linalg.norm(free) > 0.006, f"free CoM {np.round(free * 1e3, 1)} mm"  # the data do not hold it
    held = _learned_com(w_com_centroid=10.0)
    assert np.linalg.norm(held) < 0.004, f"CoM with the prior {np.round(held * 1e3, 1)} mm, true 0"


def test_com_centroid_penalty_value_and_gradient():
    A = torch.diag(torch.tensor([1 / 0.09**2, 1 / 0.03**2, 1 / 0.05**2], dtype=torch.float64))
    c = torch.tensor([0.0, 0.0, 0.05], dtype=torch.float64, requires_grad=True)
    p = com_centroid_penalty(c, torch.zeros(3, dtype=torch.float64), A)
    assert abs(p.item() - 1.0) < 1e-12  # on the ellipsoid's surface
    p.backward()
    np.testing.assert_allclose(c.grad.numpy(), [0.0, 0.0, 2 * 0.05 / 0.05**2])
    with pytest.raises(ValueError, match="w_com_centroid"):
        ContactConfig(w_com_centroid=-1.0)
