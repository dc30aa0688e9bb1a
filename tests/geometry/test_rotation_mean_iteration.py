"""The geodesic mean's fixed-point iteration, against a textbook transcription of it (oracle)."""

from __future__ import annotations

import torch

from locnerf.geometry.averaging import chordal_rotation_mean, geodesic_rotation_mean
from locnerf.geometry.so3 import so3_exp, so3_log


def textbook_geodesic_mean(rotations: torch.Tensor, weights: torch.Tensor, tolerance: float = 1e-9, iterations: int = 50) -> torch.Tensor:
    """R ← R · Exp(Σ w_i Log(Rᵀ R_i)) from the chordal mean, keeping the lowest-cost iterate."""

    def cost(mean: torch.Tensor) -> float:
        return float((weights * so3_log(mean.T @ rotations).square().sum(dim=-1)).sum())

    mean = chordal_rotation_mean(rotations, weights)
    best, best_cost = mean, cost(mean)
    for _ in range(iterations):
        step = (weights[:, None] * so3_log(mean.T @ rotations)).sum(dim=0)
        mean = mean @ so3_exp(step)
        if cost(mean) < best_cost:
            best, best_cost = mean, cost(mean)
        if float(step.norm()) < tolerance:
            break
    return best


def test_the_mean_equals_the_textbook_iteration_for_tight_and_wide_sets(generator):
    for spread in (0.01, 0.3, 1.5):
        rotations = so3_exp(torch.randn(50, 3, dtype=torch.float64, generator=generator) * spread)
        weights = torch.rand(50, dtype=torch.float64, generator=generator)
        weights /= weights.sum()
        assert torch.allclose(geodesic_rotation_mean(rotations, weights), textbook_geodesic_mean(rotations, weights), atol=1e-12)
