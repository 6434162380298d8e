"""The SDF fit's Adam step (service.sdf.fit.AdamStep) gives torch.optim.Adam's values bit for bit, alone and in a
whole fit, without importing torch._dynamo."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from service.sdf import SdfConfig, fit_sdf
from service.sdf import fit as fit_mod
from tests.sdf.plate import BOUNDS_O, plate_views


def test_step_equals_torch_adam_bit_for_bit():
    g = torch.Generator().manual_seed(0)
    target = torch.randn(5, 6, 7, generator=g)
    a = torch.nn.Parameter(torch.randn(5, 6, 7, generator=g))
    b = torch.nn.Parameter(a.detach().clone())
    ref = torch.optim.Adam([a], lr=1.0, betas=(0.9, 0.999), eps=1e-15)
    mine = fit_mod.AdamStep(b, betas=(0.9, 0.999), eps=1e-15)
    for k in range(60):
        lr = 0.01 * 0.1 ** (k / 60)
        for p in (a, b):
            p.grad = None
            (((p - target) ** 2).sum() + p.abs().mean()).backward()
        for grp in ref.param_groups:
            grp["lr"] = lr
        ref.step()
        mine.step(lr)
        assert torch.equal(a.detach(), b.detach()), k


class _TorchAdam:
    """The fit's optimiser as it was: torch.optim.Adam with its learning rate set before each step."""

    def __init__(self, param, betas, eps):
        self.opt = torch.optim.Adam([param], lr=1.0, betas=betas, eps=eps)

    def step(self, lr):
        for grp in self.opt.param_groups:
            grp["lr"] = lr
        self.opt.step()


def test_fit_is_unchanged(monkeypatch):
    rays, _ = plate_views(0.02)
    cfg = SdfConfig(resolution=24, steps=40, rays_per_step=256, samples_near=6, samples_far=4)
    mine = fit_sdf(rays, cfg, bounds_O=BOUNDS_O)
    monkeypatch.setattr(fit_mod, "AdamStep", _TorchAdam)
    ref = fit_sdf(rays, cfg, bounds_O=BOUNDS_O)
    assert np.array_equal(mine.values, ref.values)


def test_fit_does_not_import_dynamo():
    code = ("import sys; from tests.sdf.plate import BOUNDS_O, plate_views; from service.sdf import SdfConfig, fit_sdf; "
            "fit_sdf(plate_views(0.02)[0], SdfConfig(resolution=16, steps=3, rays_per_step=64), bounds_O=BOUNDS_O); "
            "print('torch._dynamo' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.stdout.strip() == "False"
