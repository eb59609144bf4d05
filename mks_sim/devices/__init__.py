"""mks_sim.devices."""
