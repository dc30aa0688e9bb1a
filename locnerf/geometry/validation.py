"""Input checks for poses and rotations: clear errors at the library's boundaries."""

from __future__ import annotations

import torch


class InvalidPoseError(ValueError):
    """A pose or rotation that is not a finite rigid transform of the expected shape."""


def validate_rotations(rotation: torch.Tensor, name: str = "rotation", atol: float = 1e-3) -> None:
    """Raise :class:`InvalidPoseError` unless ``rotation`` is (..., 3, 3), finite, orthonormal, det +1."""
    if not isinstance(rotation, torch.Tensor):
        raise InvalidPoseError(f"{name}: expected a torch.Tensor of shape (..., 3, 3), got {type(rotation).__name__}")
    if rotation.ndim < 2 or tuple(rotation.shape[-2:]) != (3, 3):
        raise InvalidPoseError(f"{name}: expected shape (..., 3, 3), got {tuple(rotation.shape)}")
    if not torch.isfinite(rotation).all():
        raise InvalidPoseError(f"{name}: contains NaN or inf; expected finite rotation matrices")
    r = rotation.double()
    eye = torch.eye(3, dtype=torch.float64, device=r.device)
    orth_err = (r.transpose(-1, -2) @ r - eye).abs().amax(dim=(-1, -2))
    if (orth_err > atol).any():
        worst = orth_err.max().item()
        raise InvalidPoseError(f"{name}: not orthonormal (max |RᵀR - I| = {worst:.3g}, tolerance {atol})")
    det = torch.linalg.det(r)
    if ((det - 1.0).abs() > atol).any():
        raise InvalidPoseError(f"{name}: determinant {det.flatten()[((det - 1).abs()).flatten().argmax()].item():.4f}, expected +1 (a reflection?)")


def validate_poses(pose: torch.Tensor, name: str = "pose", atol: float = 1e-3) -> None:
    """Raise :class:`InvalidPoseError` unless ``pose`` is (..., 4, 4) finite rigid transforms."""
    if not isinstance(pose, torch.Tensor):
        raise InvalidPoseError(f"{name}: expected a torch.Tensor of shape (..., 4, 4), got {type(pose).__name__}")
    if pose.ndim < 2 or tuple(pose.shape[-2:]) != (4, 4):
        raise InvalidPoseError(f"{name}: expected shape (..., 4, 4), got {tuple(pose.shape)}")
    if not torch.isfinite(pose).all():
        raise InvalidPoseError(f"{name}: contains NaN or inf; expected finite rigid transforms")
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=pose.dtype, device=pose.device)
    if ((pose[..., 3, :] - bottom).abs() > atol).any():
        raise InvalidPoseError(f"{name}: last row must be [0, 0, 0, 1]")
    validate_rotations(pose[..., :3, :3], name=f"{name} rotation", atol=atol)


def validate_pose_setting(value: object, name: str, atol: float = 1e-3) -> list[list[float]]:
    """A configured or transmitted extrinsic: raise :class:`InvalidPoseError` unless ``value`` is one
    finite 4×4 rigid transform given as nested lists (as :func:`validate_poses`, within ``atol``);
    returns ``value`` unchanged (for validators)."""
    try:
        pose = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError) as error:
        raise InvalidPoseError(f"{name}: expected a 4×4 list of numbers, got {value!r} ({error})") from None
    if pose.shape != (4, 4):
        raise InvalidPoseError(f"{name}: expected a finite 4×4 matrix, got shape {tuple(pose.shape)}")
    try:
        validate_poses(pose, name=name, atol=atol)
    except InvalidPoseError as error:
        raise InvalidPoseError(f"{name}: expected a rigid transform ({error}), got {value}") from None
    return value
