"""Synthetic ground truth: a procedural world that renders exactly, smooth trajectories through it,
and the one sensor simulator of locnerf (drifting VIO and a noisy camera along a camera path), used
by the offline evaluation, the services' simulated sources, the demo and the load test."""
