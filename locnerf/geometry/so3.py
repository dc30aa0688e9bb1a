"""The rotation group SO(3): exponential and logarithm maps, batched over leading dims.

Rotation vectors ``omega: (..., 3)`` map to rotation matrices ``R: (..., 3, 3)``. Both maps are
numerically stable near the identity (Taylor series) and near a half turn (the logarithm goes
through a unit quaternion, whose extraction is well conditioned at every angle).
"""

from __future__ import annotations

import torch

from locnerf.geometry.quaternion import matrix_to_quaternion, quaternion_to_rotvec

# Below this angle (radians) the closed forms lose precision; the series are used instead.
_SMALL_ANGLE = 1e-3


def hat(omega: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of a vector: ``hat(a) @ b == cross(a, b)``.

    Args:
        omega: (..., 3).
    Returns:
        (..., 3, 3).
    """
    x, y, z = omega.unbind(-1)
    zero = torch.zeros_like(x)
    rows = (
        torch.stack((zero, -z, y), dim=-1),
        torch.stack((z, zero, -x), dim=-1),
        torch.stack((-y, x, zero), dim=-1),
    )
    return torch.stack(rows, dim=-2)


def vee(skew: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`hat`: (..., 3, 3) -> (..., 3), using the antisymmetric part."""
    return 0.5 * torch.stack(
        (
            skew[..., 2, 1] - skew[..., 1, 2],
            skew[..., 0, 2] - skew[..., 2, 0],
            skew[..., 1, 0] - skew[..., 0, 1],
        ),
        dim=-1,
    )


def rodrigues_coefficients(theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Coefficients of the SO(3)/SE(3) series, evaluated stably.

    ``a = sin(θ)/θ``, ``b = (1 - cos θ)/θ²``, ``c = (θ - sin θ)/θ³``.

    Args:
        theta: (...,) non-negative angles.
    Returns:
        a, b, c: each (...,).
    """
    small = theta < _SMALL_ANGLE
    t = torch.where(small, torch.ones_like(theta), theta)  # safe denominator
    t2 = theta * theta
    a = torch.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, torch.sin(t) / t)
    b = torch.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - torch.cos(t)) / (t * t))
    c = torch.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (t - torch.sin(t)) / (t * t * t))
    return a, b, c


def so3_exp(omega: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of a rotation vector (Rodrigues): ``R = I + a K + b K²``, ``K = hat(ω)``.

    Args:
        omega: (..., 3) rotation vectors (axis × angle, radians).
    Returns:
        (..., 3, 3) rotation matrices.
    """
    theta = torch.linalg.vector_norm(omega, dim=-1)
    a, b, _ = rodrigues_coefficients(theta)
    k = hat(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand(k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def so3_log(rotation: torch.Tensor) -> torch.Tensor:
    """Rotation vector of a rotation matrix, with angle in [0, π].

    Args:
        rotation: (..., 3, 3).
    Returns:
        (..., 3).
    """
    return quaternion_to_rotvec(matrix_to_quaternion(rotation))


def rotation_angle(rotation: torch.Tensor) -> torch.Tensor:
    """Geodesic angle (radians, in [0, π]) of rotations (..., 3, 3) -> (...,)."""
    return torch.linalg.vector_norm(so3_log(rotation), dim=-1)
