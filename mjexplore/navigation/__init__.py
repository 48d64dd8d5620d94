"""Navigation: controllers that turn goals or sensor readings into (v, omega) commands."""
