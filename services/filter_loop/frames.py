"""The filter loop's frame handling: the robot's metric frames on one side, the map on the other.

Odometry of the body is carried to the camera with ``T_body_cam``; metric poses and covariances in
the map's world frame (commands, published poses and particles) are converted to and from the map
units the particles live in with the map's normalization.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from locnerf.field.protocol import MapNormalization
from locnerf.filter.estimate import ParticleEstimate

COVARIANCE_JITTER = 1e-10
"""Added to a commanded or restored covariance so that a fully converged (rank-deficient) one can be sampled."""


@dataclass(frozen=True)
class MetricEstimate:
    """An estimate as published: ``pose`` (4, 4) float64 ``T_world_cam`` in metres, its symmetric
    (6, 6) float64 tangent-space ``covariance`` (rotation rad², translation m²), ``spread`` in metres."""

    pose: torch.Tensor
    covariance: torch.Tensor
    spread: float


class FilterFrames:
    """Conversions between the robot's metric frames and the map.

    Args:
        normalization: the map's frame and scale.
        T_body_cam: (4, 4) float64 pose of the camera in the odometry's body frame, metres.
    """

    def __init__(self, normalization: MapNormalization, T_body_cam: torch.Tensor) -> None:
        self.normalization = normalization
        self.T_body_cam = T_body_cam

    def camera_odometry(self, T_odom_body: torch.Tensor) -> torch.Tensor:
        """(4, 4) odometry pose of the body -> ``T_odom_cam`` (4, 4): the filter moves camera poses."""
        return T_odom_body @ self.T_body_cam

    def map_increment(self, increment: torch.Tensor | None) -> torch.Tensor | None:
        """A metric odometry increment ``T_prev_curr`` (4, 4) in map units (None stays None: noise only)."""
        return None if increment is None else self.normalization.increment_to_map(increment)

    def particle_distribution(self, T_world_cam: torch.Tensor, covariance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A metric pose (4, 4) and its (6, 6) covariance -> the mean (4, 4) and jittered covariance
        (6, 6) in map units, float64, that particles are drawn from."""
        mean = self.normalization.metric_to_map(T_world_cam.double())
        cov = self.normalization.covariance_to_map(covariance) + COVARIANCE_JITTER * torch.eye(6, dtype=torch.float64)
        return mean, cov

    def metric_estimate(self, estimate: ParticleEstimate) -> MetricEstimate:
        """The estimate (map units) as published: metric pose, symmetrised metric covariance, spread in metres."""
        pose = self.normalization.map_to_metric(estimate.pose)
        covariance = self.normalization.covariance_to_metric(estimate.covariance)
        covariance = 0.5 * (covariance + covariance.T)
        return MetricEstimate(pose, covariance, estimate.spread / self.normalization.scale)

    def metric_poses(self, poses: torch.Tensor) -> torch.Tensor:
        """Particle poses (N, 4, 4) in map units -> (N, 4, 4) float64 metric camera poses, on the CPU."""
        return self.normalization.map_to_metric(poses.double().cpu())
