"""mks_sim.paper."""
