"""The one-parameter pose graph over frame pairs of the mixed spin estimate (service.tracking.spin.solve_spin_graph)
recovers the spins from chain links plus long links and is not pulled by gross outlier links; the solver setting is
validated."""

from __future__ import annotations

import numpy as np
import pytest

from service.tracking.spin import solve_spin_graph
from service.tracking.types import TrackingConfig


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


def test_config_refuses_bad_graph_settings():
    with pytest.raises(ValueError, match="spin_solver"):
        TrackingConfig(spin_solver="pooled")
    with pytest.raises(ValueError, match="spin_solver"):
        TrackingConfig(spin_solver="graph")  # the joint estimate alone: tried, removed
    with pytest.raises(ValueError, match="spin_graph_votes"):
        TrackingConfig(spin_graph_votes=0)
    with pytest.raises(ValueError, match="spin_graph_gate_deg"):
        TrackingConfig(spin_graph_gate_deg=-1.0)
