"""Joint spin estimate (service.tracking.spin, ``spin_solver`` "graph"): the one-parameter pose graph over frame
pairs recovers the spins from chain links plus long links, is not pulled by gross outlier links, and on the rendered
textured cylinder of test_spin recovers a 44° spin the given poses do not hold."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import solve_spin_graph, spin_graph
from service.tracking.types import TrackingConfig
from tests.tracking.test_spin import KW, _cylinder_model, _feats, _session


def test_graph_recovers_spins_and_ignores_outliers():
    rng = np.random.default_rng(0)
    n = 60
    true = np.radians(np.concatenate([np.zeros(20), np.linspace(0, -40, 20), np.full(20, -40.0)]))
    links = [(i, i - 1, true[i] - true[i - 1] + np.radians(rng.normal(0, 0.3)), 10.0) for i in range(1, n)]
    for i in range(25, n, 3):  # long links, two of them off by 30°
        j = max(i - 12, 0)
        off = np.radians(30.0) if i in (28, 46) else 0.0
        links.append((i, j, true[i] - true[j] + off, 10.0))
    th = solve_spin_graph(n, np.array(links))
    assert th[0] == 0.0
    assert np.max(np.abs(np.degrees(th - true))) < 1.5
    # without the Huber weights the outlier links pull the end of the track
    th2 = solve_spin_graph(n, np.array(links), huber_deg=1e6)
    assert np.max(np.abs(np.degrees(th2 - true))) > 2.0


def test_graph_spin_on_rendered_cylinder():
    true = np.radians(np.arange(12) * 4.0)
    s = _session(true)
    Q, N = _cylinder_model()
    X = np.tile(np.eye(4), (len(true), 1, 1))
    kw = dict(KW, min_votes=6)
    r = spin_graph(_feats(s), X, Q, N, gate_deg=3.0, **kw)
    assert r.is_revolution and r.observable and not r.rejected
    est = r.theta * np.sign(r.axis_O[0])
    assert np.max(np.abs(np.degrees(est - true))) < 2.0  # chain links only here (every frame turns): 1.5° measured


def test_config_refuses_bad_graph_settings():
    with pytest.raises(ValueError, match="spin_solver"):
        TrackingConfig(spin_solver="pooled")
    with pytest.raises(ValueError, match="spin_graph_votes"):
        TrackingConfig(spin_graph_votes=0)
    with pytest.raises(ValueError, match="spin_graph_gate_deg"):
        TrackingConfig(spin_graph_gate_deg=-1.0)
