"""The Loc-NeRF particle filter: particles, motion and measurement models, resampling, annealing,
initialisation, recovery, the estimate, and the localizer that ties them together (no I/O)."""

from locnerf.filter.convergence_protection import ConvergenceProtectionConfig
from locnerf.filter.estimate import ParticleEstimate
from locnerf.filter.localizer import Localizer, MergeOutcome, MergeReport, UpdateSnapshot
from locnerf.filter.localizer_config import LocalizerConfig, SearchRegion
from locnerf.filter.particles import ParticleSet

__all__ = [
    "ConvergenceProtectionConfig",
    "Localizer",
    "LocalizerConfig",
    "MergeOutcome",
    "MergeReport",
    "ParticleSet",
    "ParticleEstimate",
    "SearchRegion",
    "UpdateSnapshot",
]
