"""Weighted means of rotations and poses, and the covariance in the tangent space of the mean.

The rotation mean is the weighted geodesic L2 mean (Karcher mean; Hartley et al. 2013, Manton
2004): ``R* = argmin_R Σ w_i d(R, R_i)²`` with ``d`` the geodesic angle. It is initialised with the
weighted chordal L2 mean (SVD projection of ``Σ w_i R_i``) and refined with the fixed-point
iteration ``R ← R · Exp(Σ w_i Log(Rᵀ R_i) / Σ w_i)``. The function always returns a rotation: if the
iteration does not converge within its budget it returns the iterate with the lowest cost seen.
"""

from __future__ import annotations

import torch

from locnerf.geometry.so3 import so3_exp, so3_log


def _normalised_weights(weights: torch.Tensor | None, count: int, like: torch.Tensor) -> torch.Tensor:
    if weights is None:
        return torch.full((count,), 1.0 / count, dtype=like.dtype, device=like.device)
    if weights.shape != (count,):
        raise ValueError(f"weights: expected shape ({count},), got {tuple(weights.shape)}")
    if not torch.isfinite(weights).all() or (weights < 0).any():
        raise ValueError("weights: expected finite non-negative values")
    total = weights.sum()
    if total <= 0:
        raise ValueError("weights: all zero; expected a positive sum")
    return (weights / total).to(like.dtype)


def project_to_rotation(matrix: torch.Tensor) -> torch.Tensor:
    """Closest rotation in Frobenius norm to (..., 3, 3) matrices (SVD with det correction)."""
    u, _, vh = torch.linalg.svd(matrix)
    det = torch.linalg.det(u @ vh)
    fix = torch.ones(*matrix.shape[:-2], 3, dtype=matrix.dtype, device=matrix.device)
    fix[..., 2] = torch.sign(det) + (det == 0).to(matrix.dtype)
    return u @ torch.diag_embed(fix) @ vh


def chordal_rotation_mean(rotations: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Weighted chordal L2 mean of rotations (N, 3, 3) -> (3, 3)."""
    w = _normalised_weights(weights, rotations.shape[0], rotations)
    return project_to_rotation((w[:, None, None] * rotations).sum(dim=0))


def _geodesic_residuals(mean: torch.Tensor, rotations: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Residuals ``Log(meanᵀ R_i)`` (N, 3) and the cost ``Σ w_i |residual_i|²`` () at ``mean``."""
    residual = so3_log(mean.transpose(-1, -2) @ rotations)
    return residual, (w * (residual * residual).sum(dim=-1)).sum()


def geodesic_rotation_mean(
    rotations: torch.Tensor,
    weights: torch.Tensor | None = None,
    tolerance: float = 1e-9,
    max_iterations: int = 50,
) -> torch.Tensor:
    """Weighted geodesic L2 mean of rotations (N, 3, 3) -> (3, 3); always returns a rotation.

    Args:
        rotations: (N, 3, 3) rotation matrices, N >= 1.
        weights: (N,) non-negative, not all zero; ``None`` means equal weights.
        tolerance: stop when the update's angle (radians) falls below this.
        max_iterations: iteration budget; on exhaustion the lowest-cost iterate is returned.
    """
    if rotations.ndim != 3 or tuple(rotations.shape[1:]) != (3, 3) or rotations.shape[0] == 0:
        raise ValueError(f"rotations: expected shape (N>=1, 3, 3), got {tuple(rotations.shape)}")
    w = _normalised_weights(weights, rotations.shape[0], rotations)
    mean = chordal_rotation_mean(rotations, w)
    residual, best_cost = _geodesic_residuals(mean, rotations, w)
    best = mean
    for _ in range(max_iterations):
        step = (w[:, None] * residual).sum(dim=0)
        mean = mean @ so3_exp(step)
        # One Log per iteration: the residuals at the new mean give its cost and the next step.
        residual, cost = _geodesic_residuals(mean, rotations, w)
        if cost < best_cost:
            best, best_cost = mean, cost
        if torch.linalg.vector_norm(step) < tolerance:
            break
    return best


def weighted_pose_mean(poses: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Pose (4, 4) with the weighted mean position and the geodesic mean rotation of (N, 4, 4)."""
    w = _normalised_weights(weights, poses.shape[0], poses)
    mean = torch.eye(4, dtype=poses.dtype, device=poses.device)
    mean[:3, :3] = geodesic_rotation_mean(poses[:, :3, :3], w)
    mean[:3, 3] = (w[:, None] * poses[:, :3, 3]).sum(dim=0)
    return mean


def tangent_covariance(poses: torch.Tensor, mean: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """6×6 weighted covariance of poses about ``mean`` in the mean's tangent space.

    Residuals are ``(Log(R̄ᵀ R_i), R̄ᵀ (t_i - t̄))``: rotation first, both in the mean's body frame,
    consistent with the right-multiplied noise of the motion model.

    Args:
        poses: (N, 4, 4); mean: (4, 4); weights: (N,) or None.
    Returns:
        (6, 6) symmetric positive semi-definite matrix.
    """
    w = _normalised_weights(weights, poses.shape[0], poses)
    rotation_t = mean[:3, :3].transpose(0, 1)
    d_rot = so3_log(rotation_t @ poses[:, :3, :3])
    d_trans = (rotation_t @ (poses[:, :3, 3] - mean[:3, 3]).T).T
    residual = torch.cat((d_rot, d_trans), dim=-1)
    return (w[:, None, None] * residual[:, :, None] * residual[:, None, :]).sum(dim=0)
