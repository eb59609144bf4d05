"""mks_sim.lowlevel."""
