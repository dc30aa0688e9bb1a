"""What the particle filter is configured with (:class:`LocalizerConfig`, presets in :mod:`locnerf.config`) and
where a lost robot may be (:class:`SearchRegion`): the settings :class:`locnerf.filter.localizer.Localizer` is built from."""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.filter.annealing import AnnealingConfig
from locnerf.filter.convergence_protection import ConvergenceProtectionConfig
from locnerf.filter.final_search import FinalSearchConfig
from locnerf.filter.keyframe_start import KeyframeStartConfig
from locnerf.filter.kld import KldConfig
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.motion import MotionNoiseConfig
from locnerf.filter.recovery import RecoveryConfig
from locnerf.filter.resampling import ResamplerName
from locnerf.filter.tempering import TemperingConfig


class LocalizerConfig(BaseModel):
    """Everything the particle filter needs; presets in :mod:`locnerf.config`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    particles: int = Field(300, ge=1, description="Particle count while not converged (COARSE stage).")
    motion: MotionNoiseConfig = Field(default_factory=MotionNoiseConfig, description="Prediction noise δ.")
    measurement: MeasurementConfig = Field(default_factory=MeasurementConfig, description="Photometric likelihood (eq. 5).")
    annealing: AnnealingConfig = Field(default_factory=AnnealingConfig, description="Algorithm 1 coarse-to-fine schedule.")
    resampler: ResamplerName = Field("multinomial", description="Resampling scheme: multinomial (the paper) or systematic.")
    kld: KldConfig = Field(
        default_factory=KldConfig,
        description="KLD-sampling (Fox 2003): when enabled the particle count after each resampling follows the posterior's spread, "
        "between kld.min_particles and `particles`, replacing the annealing's reduced_particles (the annealing still scales the noise).",
    )
    convergence_protection: ConvergenceProtectionConfig = Field(
        default_factory=ConvergenceProtectionConfig, description="Re-drawing of a few particles before each update."
    )
    tempering: TemperingConfig = Field(
        default_factory=TemperingConfig, description="Adaptive tempering of updates on a spread cloud (off unless min_ess_fraction is set)."
    )
    recovery: RecoveryConfig = Field(default_factory=RecoveryConfig, description="Augmented-MCL kidnapping recovery.")
    keyframe_start: KeyframeStartConfig = Field(
        default_factory=KeyframeStartConfig, description="Re-drawing part of a uniform global start around the keyframes that match the first image."
    )
    final_search: FinalSearchConfig | None = Field(None, description="Single-image trials: a last local search of the estimate on fixed pixels (None: off).")
    lineage_depth: int = Field(64, ge=1, description="Resampling generations kept for merging delayed updates.")
    borrow_reach: float = Field(
        0.0,
        ge=0,
        description="Merging a delayed update: a particle drawn since its snapshot and within this Mahalanobis radius of the measured "
        "particles (4.1: 99 % of a 6-D Gaussian) takes its nearest measured neighbour's log-likelihood instead of the median (0: always the median).",
    )
    mlp_coarse_samples: int = Field(64, ge=1, description="Coarse samples per ray for the nerf-pytorch MLP backend.")
    mlp_fine_samples: int = Field(64, ge=0, description="Fine (importance) samples per ray for the nerf-pytorch MLP backend.")

    def uses_keyframes(self) -> bool:
        """Whether recovery or the keyframe start draws particles around the map's keyframes (a keyframe index is needed)."""
        return (self.recovery.enabled and self.recovery.keyframe_share > 0) or self.keyframe_start.share > 0


class SearchRegion(BaseModel):
    """Where a lost robot may be: used by global initialisation and kidnapping recovery."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    low: tuple[float, float, float] = Field(description="Minimum corner of the plausible camera positions (map units).")
    high: tuple[float, float, float] = Field(description="Maximum corner of the plausible camera positions (map units).")
    up: tuple[float, float, float] = Field((0.0, 1.0, 0.0), description="World axis opposite to gravity.")

    def bounds(self) -> torch.Tensor:
        """(2, 3) float64 [min, max] corners."""
        return torch.tensor([self.low, self.high], dtype=torch.float64)
