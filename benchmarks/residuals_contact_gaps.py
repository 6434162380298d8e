"""Diagnosis (docs/residuals-findings.md, "The hull's size from where the sphere touches it"): the strike contacts
(``loop.contact_episodes``) on all blocks of a learned-model strike session of ``benchmarks/residuals.py strike
--learned-model`` (the same session, model and settings), and the contact-gap term (``loop.contact_gap_term``: mean
over the contacts of |smallest sphere-hull gap|) for the true hull (ground truth, read here only), the learned one
(size x 1.06) and the learned one x 0.943; per principal axis of the learned model the median contact gap; and the
scale of axes 2, 3 the term alone picks (grid 0.90-1.08).

    python benchmarks/residuals_contact_gaps.py linear_damping 790 791 792
"""
import dataclasses
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from residuals import LEARNED_ERRORS
from tests.residuals.synthlab import lab_session, perturbed_model
from service.synth.types import HiddenEffects, SynthSpec
from service.residuals.effects import NUISANCE_LEARNED, principal_axes, scale_model
from service.residuals.types import ResidualConfig, ResidualInputs
from service.residuals import loop as L
from service.residuals.modes import classify, sphere_gaps
HID = {"linear_damping": {"linear_damping": 2.0}, "none": {}, "friction": {"friction_object_table": 0.3}}
case = sys.argv[1]
for seed in [int(s) for s in sys.argv[2:]]:
    ls = lab_session(SynthSpec(object="baking_box", interaction="strike", seed=seed, preset="tiny", n_frames=900, friction_object_table=0.15,
                               effects=HiddenEffects(**HID[case])), pose_noise_m=5e-4, pose_noise_rad=5e-3)
    cfg = dataclasses.replace(ResidualConfig.fast(), segment_s=0.3, seed=seed, nuisance=NUISANCE_LEARNED, folds=2)
    model = perturbed_model(ls, **LEARNED_ERRORS); true = perturbed_model(ls)
    inputs = ResidualInputs(model, (ls.trajectory,), ls.table_height, robot=(ls.robot,))
    inputs = dataclasses.replace(inputs, robot=tuple(L.smooth_robot(r, cfg) for r in inputs.robot))
    modes = [classify(model, tr, inputs.table_height, inputs.robot[k], cfg) for k, tr in enumerate(inputs.trajectories)]
    segs = L.make_segments(inputs, modes, cfg)
    ep = L.contact_episodes(segs, cfg); X, p, r, ids = ep
    def gm(m):
        return L.episode_gaps(m, ep)
    P = principal_axes(model); p_O = np.einsum("nji,nj->ni", X[:, :3, :3], p - X[:, :3, 3]) - model.com_O
    gl = sphere_gaps(model, X, p, r)
    ax = np.array([int(np.argmax(np.abs(p_O[ids == e][np.argmin(gl[ids == e])] @ P))) for e in range(ids[-1] + 1)])
    best = min(((np.mean(np.abs(gm(scale_model(model, (1.0, a, b))))), a, b) for a, b in itertools.product(np.arange(0.90, 1.081, 0.01), repeat=2)))
    gt, gL = gm(true), gm(model)
    med = "; ".join(f"axis {a+1} ({(ax==a).sum()}): true {np.median(gt[ax==a])*1e3:+.2f}, learned {np.median(gL[ax==a])*1e3:+.2f}" for a in range(3) if (ax == a).any())
    print(f"{case} {seed}: {len(segs)} blocks, {ids[-1]+1} strike contacts; term (mean |g_e|): true {np.mean(np.abs(gt))*1e3:.2f} mm, learned {np.mean(np.abs(gL))*1e3:.2f} mm, "
          f"learned x 0.943 {np.mean(np.abs(gm(scale_model(model, (0.943,)*3))))*1e3:.2f} mm; medians of g_e (mm) {med}; the term's best scale (axes 2, 3) {best[1]:.2f}, {best[2]:.2f} (truth 0.943)", flush=True)
