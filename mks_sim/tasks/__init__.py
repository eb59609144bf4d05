"""mks_sim.tasks."""
