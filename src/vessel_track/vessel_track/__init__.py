"""Multi-target Kalman tracker, screen-to-world fuser and GPS publisher for monocular vessel tracking."""
