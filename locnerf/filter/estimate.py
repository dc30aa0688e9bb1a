"""The filter's estimate: weighted mean pose, tangent-space covariance and summary figures."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from locnerf.filter.annealing import AnnealingStage
from locnerf.filter.motion import PivotNoise
from locnerf.filter.particles import ParticleSet, weighted_position_spread
from locnerf.filter.resampling import effective_sample_size as kish_effective_sample_size
from locnerf.geometry.averaging import weighted_pose_mean_and_covariance
from locnerf.geometry.so3 import hat

ROTATION_MEAN_TOLERANCE = 1e-7
"""Radians: the mean rotation's last update is smaller than this (0.02 arcsecond). The filter
computes an estimate for every pose it publishes; widely spread particles need ~18 fixed-point
iterations for 1e-9 rad and fewer for this, which is far below any error the filter can tell."""


@dataclass(frozen=True)
class ParticleEstimate:
    """One estimate of the camera pose.

    Attributes:
        pose: (4, 4) float64 ``T_world_cam`` in map units: weighted mean position, weighted
            geodesic L2 mean rotation.
        covariance: (6, 6) float64 covariance in the tangent space of ``pose`` (rotation first).
        spread: largest per-axis weighted std of particle positions (map units).
        effective_sample_size: Kish's ``1 / Σ w²``: of the weights the last update gave before
            resampling when the estimate comes from :meth:`locnerf.filter.localizer.Localizer.estimate`.
        particle_count: N.
        stage: the annealing stage of the filter.
    """

    pose: torch.Tensor
    covariance: torch.Tensor
    spread: float
    effective_sample_size: float
    particle_count: int
    stage: AnnealingStage


def estimate_from_particles(
    particles: ParticleSet, stage: AnnealingStage, include: torch.Tensor | None = None, effective_sample_size: float | None = None
) -> ParticleEstimate:
    """Compute the estimate of design section 1 from a particle set (in float64).

    Args:
        include: (N,) bool, the particles that pose, covariance and spread are computed from
            (their weights renormalised); all when None. Effective sample size and count are
            always those of the whole set.
        effective_sample_size: the value to report (the localizer passes the last update's, taken
            before resampling); ``1 / Σ w²`` of the set's weights when None.
    """
    poses = particles.poses.double().cpu()
    weights = particles.weights.double().cpu()
    effective = kish_effective_sample_size(weights) if effective_sample_size is None else effective_sample_size
    if include is not None:
        include = include.cpu()
        poses, weights = poses[include], weights[include] / weights[include].sum()
    mean, covariance = weighted_pose_mean_and_covariance(poses, weights, ROTATION_MEAN_TOLERANCE)
    return ParticleEstimate(
        pose=mean,
        covariance=covariance,
        spread=weighted_position_spread(poses[:, :3, 3], weights),
        effective_sample_size=effective,
        particle_count=particles.count,
        stage=stage,
    )


def carry_estimate(estimate: ParticleEstimate, increment: torch.Tensor | None, sigma: torch.Tensor, pivot: PivotNoise | None = None) -> ParticleEstimate:
    """The estimate moved by one prediction step (eq. 4) without touching the particles.

    Eq. 4 moves every particle by ``X·O·Exp(δ)``; its mean moves to ``pose·O`` (δ has zero mean)
    and its tangent-space covariance, to first order, to ``J Σ Jᵀ + diag(σ²)`` with
    ``J = [[R_Oᵀ, 0], [−R_Oᵀ [t_O]×, R_Oᵀ]]`` (rotation first, as in :class:`ParticleEstimate`).
    This is how the filter publishes a pose at the odometry rate between image updates, as
    amcl's map→odom transform does: the particles' weighted mean differs from it only by the
    sampling scatter of the noise draws.

    Args:
        estimate: the last estimate computed from the particles (or carried since).
        increment: (4, 4) odometry increment ``T_prev_curr`` in map units, or None (noise only).
        sigma: (6,) prediction-noise standard deviations (rotation, translation) of the step.
        pivot: the step's pivot noise, if any (its covariance is added too).
    Returns:
        The moved estimate; spread from the carried position covariance; ESS, count and stage kept.
    """
    covariance = estimate.covariance.double()
    pose = estimate.pose.double()
    if increment is not None:
        increment = increment.double()
        rotation_t = increment[:3, :3].T
        jacobian = torch.zeros(6, 6, dtype=torch.float64)
        jacobian[:3, :3] = rotation_t
        jacobian[3:, 3:] = rotation_t
        jacobian[3:, :3] = -rotation_t @ hat(increment[:3, 3])
        covariance = jacobian @ covariance @ jacobian.T
        pose = pose @ increment
    covariance = covariance + torch.diag(sigma.double() ** 2)
    if pivot is not None:
        covariance = covariance + pivot.covariance()
    world_position_covariance = pose[:3, :3] @ covariance[3:, 3:] @ pose[:3, :3].T
    spread = float(torch.sqrt(torch.diagonal(world_position_covariance).clamp_min(0.0)).max())
    return replace(estimate, pose=pose, covariance=covariance, spread=spread)
