"""The synthetic lab's strikes bounce as declared: the 10 kg sphere strikes a resting baking box through its CoM on a
frictionless table, in the lab's own world (``tests/synth/strike_lab.py``), with the touch at six places within a
physics step. A heavy striker launches the box at (1 + e) x the launch with e = 0 in every phase. The lab's default is
the step split at the time of impact (``STRIKE_TOUCH_SPLIT``); the other contacts are tested with it off. With every
contact point solved as Bullet makes it (``STRIKE_CONTACT_PROCESSING_M = None``) the point is made while
the gap is still open and the bounce is lost in some phases (here 3 of the 6); solved from the touch on
(``STRIKE_TOUCH_PROCESSING_M``, off by default) it is kept in all (docs/residuals-findings.md, "The synthetic lab's
strikes"). The contact then starts inside the box by up to v h; with Bullet's push-out of that overlap launches run up
to a few per cent above the physics (why the setting is off), with the sphere's contact solved at the velocity level only (``STRIKE_CONTACT_STIFFNESS_DAMPING`` =
``STRIKE_VELOCITY_ONLY``, off by default) they are the heavy striker's within 1 % (docs/residuals-findings.md, "The launch
kick").
"""

from __future__ import annotations

import numpy as np
import pytest

from service.synth import sim
from tests.synth.strike_lab import lab_strike

V = 0.45  # m/s, the command's speed at the surface (the sphere hits at about 0.38 m/s)
PHASES = (np.arange(6) + 0.5) / 6
E = 0.3


HEAVY = sim.STRIKE_EE_MASS / (sim.STRIKE_EE_MASS + 0.3)  # e = 0 launch / approach of a heavy striker, 0.971


def _ratios() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per phase: launch(e = 0.3) / launch(e = 0), launch(e = 0.3) / approach and launch(e = 0) / approach speed."""
    r0 = np.array([lab_strike(V, 0.0, ph) for ph in PHASES])
    r3 = np.array([lab_strike(V, E, ph) for ph in PHASES])
    return r3[:, 1] / r0[:, 1], r3[:, 1] / r3[:, 0], r0[:, 1] / r0[:, 0]


def test_lab_strike_launches_with_the_declared_restitution_in_every_phase(monkeypatch):
    assert sim.STRIKE_CONTACT_PROCESSING_M is None  # off by default
    assert sim.STRIKE_CONTACT_STIFFNESS_DAMPING is None  # the push-out is Bullet's (off by default)
    monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", False)  # the contact solved from the touch on, the step not split
    monkeypatch.setattr(sim, "STRIKE_CONTACT_PROCESSING_M", sim.STRIKE_TOUCH_PROCESSING_M)
    q, launch, launch0 = _ratios()
    assert np.all(np.abs(q - (1.0 + E)) < 0.03), q  # measured 1.280-1.297
    # a heavy striker: (1 + e) m_E / (m_E + m) = 1.262; Bullet's push-out of the penetration made in the step of the
    # touch adds up to a few per cent (measured 1.265-1.321; e = 0: 0.975-1.032 for 0.971)
    assert np.all((launch > (1.0 + E) * HEAVY - 0.01) & (launch < (1.0 + E) * HEAVY * 1.06)), launch
    assert launch0.max() > 1.03 * HEAVY, launch0


def test_velocity_only_strike_launches_at_the_heavy_strikers_speed(monkeypatch):
    """Solved at the velocity level only, the contact adds no push-out of the overlap it starts with: the launch is the
    heavy striker's within 1 % in every phase (e = 0: 0.964-0.971 for 0.971; e = 0.3: 1.253-1.260 for 1.262) and the
    bounce ratio 1.3 within 0.01 (1.298-1.300)."""
    monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", False)
    monkeypatch.setattr(sim, "STRIKE_CONTACT_PROCESSING_M", sim.STRIKE_TOUCH_PROCESSING_M)
    monkeypatch.setattr(sim, "STRIKE_CONTACT_STIFFNESS_DAMPING", sim.STRIKE_VELOCITY_ONLY)
    q, launch, launch0 = _ratios()
    assert np.all(np.abs(q - (1.0 + E)) < 0.01), q
    assert np.all(np.abs(launch / ((1.0 + E) * HEAVY) - 1.0) < 0.01), launch
    assert np.all(np.abs(launch0 / HEAVY - 1.0) < 0.01), launch0


def test_split_strike_starts_at_the_touch_and_launches_as_the_physics(monkeypatch):
    """With the step split at the time of impact (``STRIKE_TOUCH_SPLIT``, on by default) the contact starts 0.01 mm
    inside the box (Bullet's slop; the lab's step otherwise starts it up to v h = 1.6 mm inside) and the launch is the
    same strike's stepped four times finer within 1 % (measured 0.994-1.000 for e = 0 and 0.3; the contact solved from
    the touch without the split: up to 5 % above), and the bounce ratio near 1.3 (1.291-1.296; the sphere's drive
    pushes on after the impact, so it is not exactly 1 + e)."""
    assert sim.STRIKE_TOUCH_SPLIT is True  # on by default
    phases = PHASES[::2]
    out = {}
    for e in (0.0, E):
        touches = []
        lab = np.array([lab_strike(V, e, ph, touches=touches)[1] for ph in phases])
        fine = np.array([lab_strike(V, e, ph, substeps=4)[1] for ph in phases])
        assert len(touches) == len(phases), touches  # one split per strike
        assert all(0.0 < o < 1e-4 for _, o, _ in touches), touches
        assert np.all(np.abs(lab / fine - 1.0) < 0.01), lab / fine
        out[e] = lab
    assert np.all(np.abs(out[E] / out[0.0] - (1.0 + E)) < 0.015), out[E] / out[0.0]


def test_bullets_default_loses_the_bounce_in_some_phases(monkeypatch):
    monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", False)
    monkeypatch.setattr(sim, "STRIKE_CONTACT_PROCESSING_M", None)
    q, _, _ = _ratios()
    assert int((q < 1.0 + 0.7 * E).sum()) >= 2, q  # measured 1.17, 0.94, 1.08 in three of the six


def test_push_spheres_keep_bullets_default(monkeypatch):
    """The setting is the strike's: a push sphere's contact is solved as Bullet makes it (push, pivot and topple sessions
    are unchanged; their contacts are sustained, not impacts). Checked with the split off (every point as Bullet makes
    it: nothing set), with the split (the default: the strike sphere's threshold 0), and with the velocity-only law."""
    monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", False)
    import pybullet as pb

    calls = []
    real = pb.changeDynamics

    def spy(*a, **kw):
        calls.append(kw)
        return real(*a, **kw)

    monkeypatch.setattr(pb, "changeDynamics", spy)
    cid = pb.connect(pb.DIRECT)
    try:
        table = sim.add_table(cid, 0.0, 0.3, 0.0)
        for inter in ("push", "pivot", "topple", "strike"):
            calls.clear()
            sim.add_sphere(cid, inter, [0.0, 0.0, 0.5], 0.15, table)
            set_here = [kw["contactProcessingThreshold"] for kw in calls if "contactProcessingThreshold" in kw]
            assert set_here == [], inter  # off by default
            law = [(kw["contactStiffness"], kw["contactDamping"]) for kw in calls if "contactStiffness" in kw]
            assert law == [], inter  # off by default
        monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", True)  # the split implies the contact solved from the touch on
        for inter in ("push", "pivot", "topple", "strike"):
            calls.clear()
            sim.add_sphere(cid, inter, [0.0, 0.0, 0.5], 0.15, table)
            set_here = [kw["contactProcessingThreshold"] for kw in calls if "contactProcessingThreshold" in kw]
            assert set_here == ([0.0] if inter == "strike" else []), inter
        monkeypatch.setattr(sim, "STRIKE_TOUCH_SPLIT", False)
        monkeypatch.setattr(sim, "STRIKE_CONTACT_PROCESSING_M", sim.STRIKE_TOUCH_PROCESSING_M)
        monkeypatch.setattr(sim, "STRIKE_CONTACT_STIFFNESS_DAMPING", sim.STRIKE_VELOCITY_ONLY)
        for inter in ("push", "pivot", "topple", "strike"):
            calls.clear()
            sim.add_sphere(cid, inter, [0.0, 0.0, 0.5], 0.15, table)
            set_here = [kw["contactProcessingThreshold"] for kw in calls if "contactProcessingThreshold" in kw]
            assert set_here == ([0.0] if inter == "strike" else []), inter
            law = [(kw["contactStiffness"], kw["contactDamping"]) for kw in calls if "contactStiffness" in kw]
            assert law == ([sim.STRIKE_VELOCITY_ONLY] if inter == "strike" else []), inter
    finally:
        pb.disconnect(physicsClientId=cid)
