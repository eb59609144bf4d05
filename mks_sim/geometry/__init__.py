"""mks_sim.geometry."""
