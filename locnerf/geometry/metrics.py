"""Pose-error metrics used by the paper: translation distance and geodesic rotation angle."""

from __future__ import annotations

import math

import torch

from locnerf.geometry.so3 import rotation_angle


def translation_error(pose_estimate: torch.Tensor, pose_truth: torch.Tensor) -> torch.Tensor:
    """Euclidean distance between the positions of poses (..., 4, 4) -> (...,)."""
    return torch.linalg.vector_norm(pose_estimate[..., :3, 3] - pose_truth[..., :3, 3], dim=-1)


def rotation_error_deg(pose_estimate: torch.Tensor, pose_truth: torch.Tensor) -> torch.Tensor:
    """Geodesic angle in degrees between the rotations of poses (..., 4, 4) -> (...,)."""
    relative = pose_estimate[..., :3, :3].transpose(-1, -2) @ pose_truth[..., :3, :3]
    return rotation_angle(relative) * (180.0 / math.pi)
