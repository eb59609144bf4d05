"""mks_sim.sim."""
