"""Synthetic ground truth: a procedural world that renders exactly, smooth trajectories through it,
and simulated VIO and camera streams (for tests, demos and the synthetic sensor source)."""
