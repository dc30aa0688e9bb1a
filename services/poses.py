"""Pose helpers shared by the services: metric world frame <-> map units, and interpolation.

Metric poses in the map's world frame <-> the filter's map units (design section 5):

``T_map_cam = T_map_dataset · scaled(T_world_cam)``, where ``scaled`` multiplies the translation
by the map's scale (map units per metre). Covariances are in the tangent space at the pose, on the
right (``pose · Exp(δ)``), so only their translation block changes, by the scale squared.
"""

from __future__ import annotations

import torch

from locnerf.field.protocol import MapNormalization
from locnerf.geometry.se3 import pose_inverse, se3_exp, se3_log


def _scaled(pose: torch.Tensor, factor: float) -> torch.Tensor:
    out = pose.clone()
    out[..., :3, 3] = out[..., :3, 3] * factor
    return out


def _dataset_transform(normalization: MapNormalization, like: torch.Tensor) -> torch.Tensor:
    return torch.tensor(normalization.T_map_dataset, dtype=like.dtype, device=like.device)


def metric_to_map(T_world_cam: torch.Tensor, normalization: MapNormalization) -> torch.Tensor:
    """(..., 4, 4) metric world-frame poses -> map-frame poses in map units."""
    return _dataset_transform(normalization, T_world_cam) @ _scaled(T_world_cam, normalization.scale)


def map_to_metric(T_map_cam: torch.Tensor, normalization: MapNormalization) -> torch.Tensor:
    """(..., 4, 4) map-frame poses -> metric world-frame poses (inverse of :func:`metric_to_map`)."""
    return _scaled(pose_inverse(_dataset_transform(normalization, T_map_cam)) @ T_map_cam, 1.0 / normalization.scale)


def increment_to_map(T_prev_curr: torch.Tensor, normalization: MapNormalization) -> torch.Tensor:
    """A body-frame motion increment (4, 4) in metres -> map units (rotation unchanged)."""
    return _scaled(T_prev_curr, normalization.scale)


def covariance_scale(normalization: MapNormalization, to_map: bool) -> torch.Tensor:
    """(6,) factors D so that ``D Σ D`` converts a (rotation, translation) covariance."""
    factor = normalization.scale if to_map else 1.0 / normalization.scale
    return torch.tensor([1.0, 1.0, 1.0, factor, factor, factor], dtype=torch.float64)


def convert_covariance(covariance: torch.Tensor, normalization: MapNormalization, to_map: bool) -> torch.Tensor:
    """(6, 6) covariance metric -> map units (``to_map``) or back."""
    d = covariance_scale(normalization, to_map)
    return covariance.double() * d[:, None] * d[None, :]


def interpolate_pose(start: torch.Tensor, end: torch.Tensor, fraction: float) -> torch.Tensor:
    """Geodesic interpolation ``start · Exp(fraction · Log(start⁻¹ end))`` of poses (4, 4)."""
    return start @ se3_exp(fraction * se3_log(pose_inverse(start) @ end))
