"""Sim-to-recover: restitution on tosses where a few held-out rollouts diverge after the bounce.

On seed 4 (not used by the other tests) the fit is right, but after a bounce a held-out toss's rollout can
diverge (contact chaos): one toss whose error grew from 4.8 to 31 mm outweighed the eight that got better in
the earlier held-out test (percentile bootstrap of the mean per-toss difference in metres; its lower bound was
−0.8 mm) and restitution was rejected. The bound on the mean of per-toss relative improvements
(docs/residuals.md §4, rule 2) counts that toss as −1 at most. The hidden value lives only in the test.
"""

import dataclasses

from service.residuals import run
from service.residuals.types import ResidualConfig, ResidualInputs
from tests.residuals.lab import cube_model, simulate_tosses

TRUTH = 0.5


def test_restitution_found_although_a_held_out_toss_diverges():
    trajs = simulate_tosses(cube_model(), {"restitution": TRUTH}, n=20, seed=4, noise_m=1.5e-4)
    # the benchmark's setting (benchmarks/residuals.py synthetic), with its first two candidates
    cfg = dataclasses.replace(ResidualConfig.fast(), candidates=("gravity_scale", "restitution"), max_train_segments=12,
                              fit_maxiter=24, seed=4)
    out = run(ResidualInputs(cube_model(), trajs, 0.0), cfg)
    assert out.accepted == ("restitution",), [c.reason for c in out.candidates]
    assert abs(out.effects["restitution"] - TRUTH) <= 0.25 * TRUTH
    c = {c.effect: c for c in out.candidates}["restitution"]
    # its own held-out frames (every frame of a block from its first impact on: the bounce and the flight after
    # it) fall to <= 0.6x (measured 13.9 -> 7.2 mm), and so does the free flight, most of which follows a bounce
    assert c.heldout_error_after <= 0.6 * c.heldout_error_before
    ff_b, ff_a = (out.by_mode[f"rollout_{w}"]["free_flight"]["pos_err_m"] for w in ("before", "after"))
    assert ff_a <= 0.6 * ff_b
    assert out.error_after["scalar_m"] < out.error_before["scalar_m"]
    assert out.model.effects == {"restitution": out.effects["restitution"]}
