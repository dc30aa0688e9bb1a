"""Initial particle distributions: the paper's protocols, a Gaussian, and uniform bounds.

All functions return poses (N, 4, 4) in float64 on the CPU; the localizer moves them to its dtype
and device. ``up`` is the world's gravity-opposite unit axis (y for NeRF/LLFF frames, z for
NeRF-synthetic and most robot worlds).
"""

from __future__ import annotations

import math

import torch

from locnerf.geometry.conversions import axis_angle_to_matrix
from locnerf.geometry.se3 import make_pose, se3_exp
from locnerf.geometry.validation import validate_poses


def random_unit_vectors(count: int, generator: torch.Generator) -> torch.Tensor:
    """(count, 3) float64 directions uniform on the sphere."""
    v = torch.randn(count, 3, dtype=torch.float64, generator=generator)
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True)


def uniform(count: int, low: float, high: float, generator: torch.Generator) -> torch.Tensor:
    """(count,) float64 draws from U(low, high)."""
    return low + (high - low) * torch.rand(count, dtype=torch.float64, generator=generator)


def random_axis_rotations(count: int, max_angle_rad: float, generator: torch.Generator) -> torch.Tensor:
    """Rotations by an angle uniform in [-max, max] about a uniformly random axis: (count, 3, 3)."""
    return axis_angle_to_matrix(random_unit_vectors(count, generator), uniform(count, -max_angle_rad, max_angle_rad, generator))


def inerf_particles(
    center: torch.Tensor,
    count: int,
    generator: torch.Generator,
    translation_half_width: float = 0.1,
    max_angle_deg: float = 40.0,
) -> torch.Tensor:
    """The iNeRF protocol (paper eq. 6) as Loc-NeRF spreads it over particles.

    Each particle's position is ``center``'s plus U(±translation_half_width) per axis, and its
    rotation is ``center``'s rotated by an angle in ±max_angle_deg about its own random axis.

    Args:
        center: (4, 4) pose the particles are spread around.
    Returns:
        (count, 4, 4) float64.
    """
    validate_poses(center, name="center pose")
    c = center.double().cpu()
    rotations = c[:3, :3] @ random_axis_rotations(count, math.radians(max_angle_deg), generator)
    offsets = uniform(count * 3, -translation_half_width, translation_half_width, generator).reshape(count, 3)
    return make_pose(rotations, c[:3, 3] + offsets)


def rotation_about_axis(axis: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Rotations (N, 3, 3) by angles (N,) about one fixed axis (3,)."""
    return axis_angle_to_matrix(axis.expand(angles.shape[0], 3), angles)


def level_rotation(up: tuple[float, float, float]) -> torch.Tensor:
    """A level camera for a world whose gravity-opposite axis is ``up``: (3, 3) float64 ``R_world_cam``.

    The camera (OpenGL axes: x right, y up, z backwards) has its y axis along ``up``, so it looks
    horizontally (along −z); it is the shortest turn taking the world's y onto ``up`` (the identity
    for y-up worlds, a half turn about x for −y). Its heading is arbitrary: callers turn it about ``up``.
    """
    axis = torch.tensor(up, dtype=torch.float64)
    norm = torch.linalg.vector_norm(axis)
    if not bool(torch.isfinite(axis).all()) or float(norm) < 1e-9:
        raise ValueError(f"up={up}: expected a finite non-zero 3-vector")
    axis = axis / norm
    y = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    turn = torch.linalg.cross(y, axis)  # sin(angle) · turn axis
    sine, cosine = torch.linalg.vector_norm(turn), torch.dot(y, axis)
    if float(sine) < 1e-12:
        return torch.eye(3, dtype=torch.float64) if float(cosine) > 0 else torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    return axis_angle_to_matrix(turn / sine, torch.atan2(sine, cosine))


def global_particles(
    center: torch.Tensor,
    count: int,
    generator: torch.Generator,
    half_width: float = 1.0,
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
    max_yaw: float = math.pi,
) -> torch.Tensor:
    """The paper's global protocol: positions uniform in a cube, yaw uniform, roll/pitch known.

    Positions are uniform in ``center ± half_width`` per axis; each rotation is ``center``'s
    rotation turned by a uniform yaw in [-max_yaw, max_yaw) (the whole circle by default) about
    the world ``up`` axis, which keeps the direction of gravity in the camera frame (roll and
    pitch) exactly.

    Args:
        center: (4, 4) pose whose position is the cube's centre and whose tilt is the known one.
        max_yaw: bound of the yaw turn, radians (π: any heading).
    Returns:
        (count, 4, 4) float64.
    """
    validate_poses(center, name="center pose")
    c = center.double().cpu()
    axis = torch.tensor(up, dtype=torch.float64)
    yaw = rotation_about_axis(axis / axis.norm(), uniform(count, -max_yaw, max_yaw, generator))
    offsets = uniform(count * 3, -half_width, half_width, generator).reshape(count, 3)
    return make_pose(yaw @ c[:3, :3], c[:3, 3] + offsets)


def gaussian_particles(mean: torch.Tensor, covariance: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """``X_i = mean · Exp(L z_i)``, ``z_i ~ N(0, I)``, ``L Lᵀ = covariance`` (6×6, rotation first).

    Raises:
        ValueError: if the covariance is not a finite symmetric positive semi-definite 6×6 matrix.
    """
    validate_poses(mean, name="mean pose")
    cov = covariance.double().cpu()
    if tuple(cov.shape) != (6, 6) or not torch.isfinite(cov).all():
        raise ValueError(f"covariance: expected a finite (6, 6) matrix, got shape {tuple(cov.shape)}")
    if (cov - cov.T).abs().max() > 1e-9 * max(1.0, float(cov.abs().max())):
        raise ValueError("covariance: expected a symmetric matrix")
    eigenvalues, eigenvectors = torch.linalg.eigh(cov)
    if float(eigenvalues.min()) < -1e-12 * max(1.0, float(eigenvalues.abs().max())):
        raise ValueError(f"covariance: not positive semi-definite (smallest eigenvalue {float(eigenvalues.min()):.3g})")
    root = eigenvectors * torch.sqrt(eigenvalues.clamp_min(0.0))
    z = torch.randn(count, 6, dtype=torch.float64, generator=generator)
    return mean.double().cpu() @ se3_exp(z @ root.T)


def uniform_particles(
    bounds: torch.Tensor,
    count: int,
    generator: torch.Generator,
    tilt: torch.Tensor | None = None,
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> torch.Tensor:
    """Positions uniform in an axis-aligned box, yaw uniform about ``up``, a fixed tilt.

    Args:
        bounds: (2, 3) min and max corners.
        tilt: (3, 3) rotation giving the known roll/pitch; level (:func:`level_rotation` of ``up``) when None.
    Returns:
        (count, 4, 4) float64.
    """
    b = bounds.double().cpu()
    if tuple(b.shape) != (2, 3) or not torch.isfinite(b).all() or (b[1] < b[0]).any():
        raise ValueError(f"bounds: expected finite (2, 3) [min, max] corners with min <= max, got {b.tolist()}")
    base = level_rotation(up) if tilt is None else tilt.double().cpu()
    axis = torch.tensor(up, dtype=torch.float64)
    yaw = rotation_about_axis(axis / axis.norm(), uniform(count, -math.pi, math.pi, generator))
    positions = b[0] + (b[1] - b[0]) * torch.rand(count, 3, dtype=torch.float64, generator=generator)
    return make_pose(yaw @ base, positions)
