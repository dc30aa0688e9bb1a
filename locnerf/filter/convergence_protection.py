"""Loc-NeRF's "convergence protection": before each update, a few particle positions are re-drawn
uniformly around the weighted mean, so that a cloud collapsed onto a wrong spot keeps some
hypotheses nearby. This module draws them; the localizer gives the re-drawn particles new ids
(design section 3)."""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.filter import initialization


class ConvergenceProtectionConfig(BaseModel):
    """Loc-NeRF's "convergence protection": before each update, re-draw a few particles near the mean."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    count: int = Field(10, ge=0, description="Particles whose positions are re-drawn before each update (0 disables).")
    half_width: float = Field(0.2, ge=0, description="Re-drawn positions are uniform in mean ± half_width per axis (map units).")


def redrawn_positions(
    positions: torch.Tensor, weights: torch.Tensor, config: ConvergenceProtectionConfig, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Which particles to re-draw and where, or None when protection is off.

    Args:
        positions: (N, 3) particle positions; weights: (N,) normalised weights.
    Returns:
        chosen: (K,) int64 indices, K = min(count, N), on ``positions``' device; new positions (K, 3),
        uniform in weighted mean ± ``half_width`` per axis, in ``positions``' dtype.
    """
    count = min(config.count, positions.shape[0])
    if count == 0 or config.half_width == 0:
        return None
    mean = (weights[:, None] * positions).sum(dim=0)
    chosen = torch.randperm(positions.shape[0], generator=generator).to(positions.device)
    offsets = initialization.uniform(count * 3, -config.half_width, config.half_width, generator)
    return chosen[:count], mean + offsets.reshape(count, 3).to(positions.device, positions.dtype)
