"""Conversions between rotation parameterisations, named ``<from>_to_<to>``.

Yaw-pitch-roll follows gtsam's ``Rot3.ypr()``: ``R = Rz(yaw) · Ry(pitch) · Rx(roll)`` with the
standard right-handed elementary rotations.
"""

from __future__ import annotations

import torch

from locnerf.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from locnerf.geometry.so3 import so3_exp, so3_log

rotvec_to_matrix = so3_exp
matrix_to_rotvec = so3_log
__all__ = [
    "rotvec_to_matrix",
    "matrix_to_rotvec",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "ypr_to_matrix",
    "matrix_to_ypr",
    "axis_angle_to_matrix",
]


def _elementary(angle: torch.Tensor, axis: int) -> torch.Tensor:
    """Right-handed rotation by ``angle: (...,)`` about coordinate ``axis`` -> (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    elif axis == 1:
        rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def ypr_to_matrix(ypr: torch.Tensor) -> torch.Tensor:
    """``(..., 3) = (yaw, pitch, roll)`` radians -> ``Rz(yaw) Ry(pitch) Rx(roll)``: (..., 3, 3)."""
    return _elementary(ypr[..., 0], 2) @ _elementary(ypr[..., 1], 1) @ _elementary(ypr[..., 2], 0)


def matrix_to_ypr(rotation: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`ypr_to_matrix`: (..., 3, 3) -> (..., 3) with pitch in [-π/2, π/2].

    At gimbal lock (pitch = ±π/2) roll is set to 0 and yaw absorbs the remaining rotation.
    """
    r = rotation
    pitch = torch.asin(torch.clamp(-r[..., 2, 0], -1.0, 1.0))
    locked = (1.0 - r[..., 2, 0].abs()) < 1e-9
    yaw = torch.where(locked, torch.atan2(-r[..., 0, 1], r[..., 1, 1]), torch.atan2(r[..., 1, 0], r[..., 0, 0]))
    roll = torch.where(locked, torch.zeros_like(pitch), torch.atan2(r[..., 2, 1], r[..., 2, 2]))
    return torch.stack((yaw, pitch, roll), dim=-1)


def axis_angle_to_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation by ``angle: (...,)`` about unit-normalised ``axis: (..., 3)`` -> (..., 3, 3)."""
    unit = axis / torch.linalg.vector_norm(axis, dim=-1, keepdim=True)
    return so3_exp(unit * angle[..., None])
