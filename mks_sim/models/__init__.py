"""mks_sim.models."""
