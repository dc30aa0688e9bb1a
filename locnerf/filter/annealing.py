"""Coarse-to-fine annealing (the paper's Algorithm 1).

When the spread of particle positions falls below α_refine the prediction noise is divided by 2
and the particle count reduced to ``reduced_particles``; below α_super_refine the noise is divided
by 4. When the spread grows again the stage goes back: noise and particle count are restored.
"""

from __future__ import annotations

import enum

from pydantic import BaseModel, ConfigDict, Field, model_validator


class AnnealingStage(enum.StrEnum):
    """How far the filter has converged (the values are the ``mode`` of the wire PoseEstimate)."""

    COARSE = "coarse"
    REFINE = "refine"
    SUPER_REFINE = "super_refine"


class AnnealingConfig(BaseModel):
    """Thresholds and effects of Algorithm 1."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Apply Algorithm 1; when false the filter stays COARSE.")
    alpha_refine: float = Field(0.08, gt=0, description="Spread (map units) below which the REFINE stage starts.")
    alpha_super_refine: float = Field(0.03, gt=0, description="Spread (map units) below which SUPER_REFINE starts.")
    refine_noise_divisor: float = Field(2.0, ge=1, description="Prediction noise divisor in REFINE.")
    super_refine_noise_divisor: float = Field(4.0, ge=1, description="Prediction noise divisor in SUPER_REFINE.")
    reduced_particles: int = Field(100, ge=1, description="Particle count in REFINE and SUPER_REFINE (reached by resampling).")

    @model_validator(mode="after")
    def _ordered(self) -> AnnealingConfig:
        if self.alpha_super_refine > self.alpha_refine:
            raise ValueError(
                f"alpha_super_refine={self.alpha_super_refine} > alpha_refine={self.alpha_refine}: expected super-refine threshold <= refine threshold"
            )
        return self


def stage_for_spread(spread: float, config: AnnealingConfig) -> AnnealingStage:
    """The stage Algorithm 1 prescribes for a particle spread (map units)."""
    if not config.enabled or spread >= config.alpha_refine:
        return AnnealingStage.COARSE
    if spread < config.alpha_super_refine:
        return AnnealingStage.SUPER_REFINE
    return AnnealingStage.REFINE


def noise_scale(stage: AnnealingStage, config: AnnealingConfig) -> float:
    """Multiplier of the prediction noise in a stage."""
    return {
        AnnealingStage.COARSE: 1.0,
        AnnealingStage.REFINE: 1.0 / config.refine_noise_divisor,
        AnnealingStage.SUPER_REFINE: 1.0 / config.super_refine_noise_divisor,
    }[stage]


def particle_count(stage: AnnealingStage, full_count: int, config: AnnealingConfig) -> int:
    """Particle count in a stage: the full count while COARSE, the reduced count after."""
    return full_count if stage is AnnealingStage.COARSE else min(config.reduced_particles, full_count)
