"""mks_sim.sensing."""
