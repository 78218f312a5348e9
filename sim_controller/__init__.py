"""sim_controller."""
