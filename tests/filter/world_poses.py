"""Poses in the procedural world shared by the measurement tests: a true camera pose and poses scattered around it."""

from __future__ import annotations

import torch

from locnerf.geometry import se3_exp
from locnerf.sim.world import ProceduralWorld


def true_pose(world: ProceduralWorld, seed: int = 3) -> torch.Tensor:
    """A plausible camera pose (4, 4) float64 of the world, drawn with ``seed``."""
    return world.sample_camera_pose(torch.Generator().manual_seed(seed)).double()


def poses_around(pose: torch.Tensor, count: int, rotation: float, translation: float, generator: torch.Generator) -> torch.Tensor:
    """(count, 4, 4) float64 poses ``pose · Exp(δ)`` with δ Gaussian (rotation first)."""
    sigma = torch.tensor([rotation] * 3 + [translation] * 3, dtype=torch.float64)
    return pose[None] @ se3_exp(torch.randn(count, 6, generator=generator, dtype=torch.float64) * sigma)
