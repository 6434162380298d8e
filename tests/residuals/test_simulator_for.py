"""The loop's built-in simulator carries every replay setting of its config (the diagnosis scripts replay with it)."""

from service.residuals.simulate import simulator_for
from service.residuals.types import ResidualConfig


def test_simulator_for_carries_the_settings():
    cfg = ResidualConfig(sim_substep_s=0.004, contact_breaking_m=0.003, sphere_drive="inverse",
                         contact_persist_m=0.02)
    with simulator_for(cfg) as sim:
        assert (sim.substep, sim.contact_breaking, sim.sphere_drive, sim.contact_persist) == (0.004, 0.003, "inverse", 0.02)
    with simulator_for(ResidualConfig(touch_split=True)) as sim:
        assert sim.touch_split
    with simulator_for(ResidualConfig(restitution_threshold_mps=0.2)) as sim:
        assert sim.restitution_threshold == 0.2


def test_simulator_for_the_defaults_is_the_loops():
    cfg = ResidualConfig()
    with simulator_for(cfg) as sim:
        assert sim.contact_breaking == cfg.contact_breaking_m == 0.001
        assert sim.sphere_drive == cfg.sphere_drive
        assert sim.contact_persist is None
        assert sim.touch_split is cfg.touch_split is True
        assert sim.restitution_threshold == cfg.restitution_threshold_mps == 0.05
