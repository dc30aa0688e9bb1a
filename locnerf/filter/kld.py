"""KLD-sampling (Fox 2003): as many particles as the posterior's spread needs.

Resampling draws particles one at a time and stops as soon as the sample size ``n`` reaches the
bound that keeps the Kullback-Leibler divergence between the sample-based (histogram) posterior
and the true one below ε with probability 1 − δ, for the ``k`` histogram bins occupied so far
(Fox, "Adapting the sample size in particle filters through KLD-sampling", IJRR 2003, eq. 13,
the Wilson-Hilferty approximation of the χ² quantile):

    n(k) = (k − 1) / (2ε) · (1 − 2 / (9(k − 1)) + sqrt(2 / (9(k − 1))) · z_{1−δ})³

and never fewer than ``min_particles`` nor more than the filter's full count. A concentrated
posterior occupies few bins, so few particles suffice; a spread one (global localization) fills
many bins and gets the full count.

Bins: the 6-DoF pose split into a position cell (``bin_translation`` map units per axis) and a
rotation cell (``bin_rotation_deg`` per axis of the rotation vector ``Log(R)``), so k counts the
distinct (x, y, z, ω) cells. nav2_amcl bins (x, y, yaw) at 0.5 m × 0.5 m × 10° for a planar robot;
a camera in 6-DoF needs the full pose. The defaults (0.02 map units, 2°) are about the tracking
accuracy the lego orbit asks for (≤ 0.02 units, ≤ 1°): a filter converged to that accuracy
occupies a handful of cells.

Differences from nav2_amcl: ``z`` is used as the normal quantile itself, as nav2's ``pf_z`` is
(nav2's default 0.99 is used as z, i.e. δ ≈ 0.16, not δ = 0.01); with one occupied bin the bound
is 0 (Fox), where nav2 returns the maximum; draws come from the configured resampler in a random
order (so a prefix of systematic draws is not a prefix of the CDF).
"""

from __future__ import annotations

import math

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.so3 import so3_log


class KldConfig(BaseModel):
    """KLD-sampling as a resampling option; the maximum is the filter's ``particles``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(False, description="Resample to the KLD bound instead of the annealing's fixed counts.")
    epsilon: float = Field(0.05, gt=0, description="ε (nav2 pf_err): the bound on the KL divergence of the histogram posterior.")
    z: float = Field(2.326, gt=0, description="z_{1−δ} (nav2 pf_z): the upper standard normal quantile; 2.326 is δ = 0.01.")
    min_particles: int = Field(100, ge=1, description="Fewest particles kept (nav2 min_particles); the maximum is LocalizerConfig.particles.")
    bin_translation: float = Field(0.02, gt=0, description="Histogram cell side along each position axis, map units.")
    bin_rotation_deg: float = Field(2.0, gt=0, description="Histogram cell side along each rotation-vector axis, degrees.")


def kld_bound(bins: torch.Tensor, epsilon: float, z: float) -> torch.Tensor:
    """Fox's sample-size bound n(k) for occupied bin counts ``bins`` (...,) int -> (...,) float64 (not rounded; 0 for k ≤ 1)."""
    k = bins.double()
    dof = (k - 1).clamp(min=1.0)
    a = 2.0 / (9.0 * dof)
    n = dof / (2.0 * epsilon) * (1.0 - a + torch.sqrt(a) * z) ** 3
    return torch.where(k > 1, n, torch.zeros_like(n))


def pose_bins(poses: torch.Tensor, config: KldConfig) -> torch.Tensor:
    """Integer histogram cells (N, 6) int64 of poses (N, 4, 4): position, then rotation vector."""
    position = torch.floor(poses[:, :3, 3].double() / config.bin_translation)
    rotation = torch.floor(so3_log(poses[:, :3, :3].double()) / math.radians(config.bin_rotation_deg))
    return torch.cat([position, rotation], dim=1).long()


def kld_sample_size(cells: torch.Tensor, config: KldConfig, max_particles: int) -> int:
    """How many of the draws (in order) KLD-sampling keeps: the first n with n ≥ n(k_n) and
    n ≥ min_particles, where k_n counts the cells ``cells`` (D, 6) hit by draws 1..n; D if none.

    All D draws are binned at once: k_n is the running count of first visits to a cell.
    """
    count = cells.shape[0]
    _, cell = torch.unique(cells, dim=0, return_inverse=True)
    order = torch.arange(count, device=cell.device)
    first_visit = torch.full((int(cell.max()) + 1,), count, dtype=torch.long, device=cell.device).scatter_reduce(0, cell, order, "amin")
    occupied = torch.cumsum((first_visit[cell] == order).long(), dim=0)
    n = order + 1
    enough = (n >= kld_bound(occupied, config.epsilon, config.z).ceil()) & (n >= min(config.min_particles, max_particles))
    hits = torch.nonzero(enough)
    return int(hits[0]) + 1 if hits.numel() else min(count, max_particles)


def kld_resample(weights: torch.Tensor, poses: torch.Tensor, config: KldConfig, max_particles: int, resampler, generator: torch.Generator) -> torch.Tensor:
    """Indices (n,) int64 of the particles kept, ``min_particles ≤ n ≤ max_particles``.

    Args:
        weights: (N,) normalised weights.
        poses: (N, 4, 4) particle poses (map units).
        resampler: a :mod:`locnerf.filter.resampling` function, drawing ``max_particles`` indices.
    """
    draws = resampler(weights, max_particles, generator)
    draws = draws[torch.randperm(max_particles, generator=generator).to(draws.device)]
    size = kld_sample_size(pose_bins(poses[draws], config), config, max_particles)
    return draws[:size]
