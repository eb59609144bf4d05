"""mks_sim.io."""
