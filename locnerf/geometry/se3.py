"""Rigid transforms SE(3) as 4×4 matrices: exp/log, compose, inverse, construction.

Tangent vectors are ``xi = (omega, rho)``: rotation part first, then translation, as the Loc-NeRF
paper writes its noise δ. ``se3_exp(xi) = [[exp(ω), V ρ], [0, 1]]`` with
``V = I + b K + c K²`` (coefficients from :func:`rodrigues_coefficients`).
"""

from __future__ import annotations

import torch

from locnerf.geometry.so3 import hat, rodrigues_coefficients, so3_exp, so3_log


def make_pose(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """Stack ``rotation: (..., 3, 3)`` and ``translation: (..., 3)`` into poses (..., 4, 4)."""
    # The batch shapes broadcast as in one elementwise op (torch.broadcast_shapes costs ~0.3 ms per call on CPU).
    batch = (rotation[..., 0, 0] + translation[..., 0]).shape
    top = torch.cat((rotation.expand(*batch, 3, 3), translation[..., None].expand(*batch, 3, 1)), dim=-1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=rotation.dtype, device=rotation.device).expand(*batch, 1, 4)
    return torch.cat((top, bottom), dim=-2)


def pose_inverse(pose: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms (..., 4, 4), using ``R^T`` rather than a general inverse."""
    rotation_t = pose[..., :3, :3].transpose(-1, -2)
    return make_pose(rotation_t, -(rotation_t @ pose[..., :3, 3:4]).squeeze(-1))


def _left_jacobian_inverse(omega: torch.Tensor) -> torch.Tensor:
    """``V⁻¹ = I - K/2 + e K²`` with ``e = (1 - a/(2b))/θ²`` (series 1/12 + θ²/720 near 0)."""
    theta = torch.linalg.vector_norm(omega, dim=-1)
    a, b, _ = rodrigues_coefficients(theta)
    small = theta < 1e-3
    safe_theta = torch.where(small, torch.ones_like(theta), theta)
    e = torch.where(small, 1.0 / 12.0 + theta * theta / 720.0, (1.0 - a / (2.0 * b)) / (safe_theta**2))
    k = hat(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand(k.shape)
    return eye - 0.5 * k + e[..., None, None] * (k @ k)


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """Exponential map: tangent vectors ``(..., 6) = (ω, ρ)`` -> poses (..., 4, 4)."""
    omega, rho = xi[..., :3], xi[..., 3:]
    theta = torch.linalg.vector_norm(omega, dim=-1)
    _, b, c = rodrigues_coefficients(theta)
    k = hat(omega)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand(k.shape)
    v = eye + b[..., None, None] * k + c[..., None, None] * (k @ k)
    return make_pose(so3_exp(omega), (v @ rho[..., None]).squeeze(-1))


def se3_log(pose: torch.Tensor) -> torch.Tensor:
    """Logarithm map: poses (..., 4, 4) -> tangent vectors ``(..., 6) = (ω, ρ)``."""
    omega = so3_log(pose[..., :3, :3])
    rho = (_left_jacobian_inverse(omega) @ pose[..., :3, 3:4]).squeeze(-1)
    return torch.cat((omega, rho), dim=-1)


def relative_pose(pose_a: torch.Tensor, pose_b: torch.Tensor) -> torch.Tensor:
    """``T_a_b = T_world_a⁻¹ · T_world_b`` for poses (..., 4, 4)."""
    return pose_inverse(pose_a) @ pose_b


def adjoint(pose: torch.Tensor) -> torch.Tensor:
    """Adjoint (6, 6) float64 of a pose (4, 4) for (rotation, translation) tangents: ``T Exp(δ) T⁻¹ = Exp(Ad_T δ)``.

    ``Ad_T = [[R, 0], [t^ R, R]]``. A covariance Σ of a right perturbation of ``X`` becomes
    ``Ad_{O⁻¹} Σ Ad_{O⁻¹}ᵀ`` for ``X · O`` (``X Exp(δ) O = X O Exp(Ad_{O⁻¹} δ)``).
    """
    rotation, translation = pose[:3, :3].double(), pose[:3, 3].double()
    out = torch.zeros(6, 6, dtype=torch.float64)
    out[:3, :3] = rotation
    out[3:, 3:] = rotation
    out[3:, :3] = hat(translation) @ rotation
    return out


def interpolate_pose(start: torch.Tensor, end: torch.Tensor, fraction: float) -> torch.Tensor:
    """Geodesic interpolation ``start · Exp(fraction · Log(start⁻¹ end))`` of poses (..., 4, 4): 0 gives start, 1 end."""
    return start @ se3_exp(fraction * se3_log(relative_pose(start, end)))
