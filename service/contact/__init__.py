"""Contact-implicit dynamics learning (PLL / ContactNets loss): convex geometry, CoM and inertia from motion.

Entry points (imported lazily so that importing ``service.contact.types`` does not pull in torch):
``run(ContactInputs, ContactConfig, *, progress=None) -> ContactOutputs``,
``inputs_from_tracking(session, tracking_outputs, visible_points, mass) -> ContactInputs``,
``fit_trajectories(npz_path, *, out_dir, cfg, train_ids=None, ...)``.
"""

from __future__ import annotations


def run(inputs, cfg, *, progress=None):
    from service.contact.fit import run as _run

    return _run(inputs, cfg, progress=progress)


def inputs_from_tracking(session, tracking_outputs, visible_points, mass):
    from service.contact.data import inputs_from_tracking as _f

    return _f(session, tracking_outputs, visible_points, mass)


def fit_trajectories(npz_path, *, out_dir, cfg=None, train_ids=None, **kwargs):
    from service.contact.data import fit_trajectories as _f

    return _f(npz_path, out_dir=out_dir, cfg=cfg, train_ids=train_ids, **kwargs)
