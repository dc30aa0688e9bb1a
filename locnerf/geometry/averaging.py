"""Weighted means of rotations and poses, and the covariance in the tangent space of the mean.

The rotation mean is the weighted geodesic L2 mean (Karcher mean; Hartley et al. 2013, Manton
2004): ``R* = argmin_R Σ w_i d(R, R_i)²`` with ``d`` the geodesic angle. It is initialised with the
weighted chordal L2 mean (SVD projection of ``Σ w_i R_i``) and refined with the fixed-point
iteration ``R ← R · Exp(Σ w_i Log(Rᵀ R_i) / Σ w_i)``. The function always returns a rotation: if the
iteration does not converge within its budget it returns the iterate with the lowest cost seen.
The iteration runs on quaternions, in NumPy float64 (design: the filter computes this mean for every pose it
publishes, so its cost is in the pose stream's latency; a Newton step was tried and converged in
fewer but dearer iterations, no faster in all).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from locnerf.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from locnerf.geometry.so3 import so3_log


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


def _quaternion_floats(rotation: torch.Tensor) -> tuple[float, float, float, float]:
    """(w, x, y, z) of one rotation matrix (3, 3), as Python floats."""
    w, x, y, z = matrix_to_quaternion(rotation).tolist()
    return w, x, y, z


def _geodesic_residuals(mean: tuple[float, float, float, float], quaternions: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Residuals ``Log(meanᵀ R_i)`` (N, 3) and the cost ``Σ w_i |residual_i|²`` at ``mean``.

    ``quaternions`` (N, 4) float64 are the R_i; ``r_i = conj(mean) ⊗ q_i`` is one (N, 4) @ (4, 4)
    product with the left-multiplication matrix of ``conj(mean)``, and its rotation vector is
    ``±2·atan2(|v|, |w|)·v/|v|`` (see :func:`locnerf.geometry.quaternion.quaternion_to_rotvec`). In
    NumPy: on a few hundred rows its per-call cost is a third of torch's, and this runs 1–20 times
    for every published pose.
    """
    a, b, c, d = mean
    left_conjugate = np.array([[a, b, c, d], [-b, a, d, -c], [-c, -d, a, b], [-d, c, -b, a]])
    relative = quaternions @ left_conjugate.T
    vector = relative[:, 1:]
    norm = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    factor = np.where(relative[:, 0] < 0, -2.0, 2.0) * np.arctan2(norm, np.abs(relative[:, 0])) / np.maximum(norm, np.finfo(np.float64).tiny)
    residual = vector * factor[:, None]
    return residual, float(w @ np.einsum("ij,ij->i", residual, residual))


def _times_exp(mean: tuple[float, float, float, float], step: list[float]) -> tuple[float, float, float, float]:
    """``mean ⊗ Exp(step)`` for a quaternion ``mean`` and a rotation vector ``step`` (3 floats), unit norm."""
    angle = math.sqrt(sum(v * v for v in step))
    # sin(θ/2)/θ -> 1/2 - θ²/48 for small θ.
    scale = 0.5 - angle * angle / 48.0 if angle < 1e-6 else math.sin(0.5 * angle) / angle
    e, f, g, h = math.cos(0.5 * angle), scale * step[0], scale * step[1], scale * step[2]
    a, b, c, d = mean
    product = (a * e - b * f - c * g - d * h, a * f + b * e + c * h - d * g, a * g - b * h + c * e + d * f, a * h + b * g - c * f + d * e)
    norm = math.sqrt(sum(v * v for v in product))
    return product[0] / norm, product[1] / norm, product[2] / norm, product[3] / norm


def _geodesic_mean_and_residuals(rotations: torch.Tensor, w: torch.Tensor, tolerance: float, max_iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The iteration of :func:`geodesic_rotation_mean` on normalised weights ``w`` (N,).

    Iterates on quaternions (the R_i converted once; the mean kept as four floats), which is the
    matrix iteration of the module docstring without its per-step matrix Log.

    Returns:
        the mean (3, 3) and the residuals ``Log(meanᵀ R_i)`` (N, 3) at it.
    """
    quaternions = matrix_to_quaternion(rotations).detach().cpu().double().numpy()
    mean = _quaternion_floats(chordal_rotation_mean(rotations, w))
    weights = w.detach().cpu().double().numpy()
    residual, best_cost = _geodesic_residuals(mean, quaternions, weights)
    best, best_residual = mean, residual
    for _ in range(max_iterations):
        step = (weights @ residual).tolist()
        mean = _times_exp(mean, step)
        # One Log per iteration: the residuals at the new mean give its cost and the next step.
        residual, cost = _geodesic_residuals(mean, quaternions, weights)
        if cost < best_cost:
            best, best_cost, best_residual = mean, cost, residual
        if math.sqrt(sum(v * v for v in step)) < tolerance:
            break
    matrix = quaternion_to_matrix(torch.tensor(best, dtype=rotations.dtype, device=rotations.device))
    return matrix, torch.from_numpy(best_residual).to(rotations.device, rotations.dtype)


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
    _check_rotations(rotations)
    w = _normalised_weights(weights, rotations.shape[0], rotations)
    return _geodesic_mean_and_residuals(rotations, w, tolerance, max_iterations)[0]


def _check_rotations(rotations: torch.Tensor) -> None:
    if rotations.ndim != 3 or tuple(rotations.shape[1:]) != (3, 3) or rotations.shape[0] == 0:
        raise ValueError(f"rotations: expected shape (N>=1, 3, 3), got {tuple(rotations.shape)}")


def weighted_pose_mean(poses: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Pose (4, 4) with the weighted mean position and the geodesic mean rotation of (N, 4, 4)."""
    return weighted_pose_mean_and_covariance(poses, weights)[0]


def weighted_pose_mean_and_covariance(poses: torch.Tensor, weights: torch.Tensor | None = None, tolerance: float = 1e-9) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`weighted_pose_mean` (4, 4) and :func:`tangent_covariance` (6, 6) about it, sharing the rotation residuals.

    ``tolerance`` is the rotation mean's (:func:`geodesic_rotation_mean`).
    """
    _check_rotations(poses[:, :3, :3])
    w = _normalised_weights(weights, poses.shape[0], poses)
    mean = torch.eye(4, dtype=poses.dtype, device=poses.device)
    mean[:3, :3], d_rot = _geodesic_mean_and_residuals(poses[:, :3, :3], w, tolerance, 50)
    mean[:3, 3] = (w[:, None] * poses[:, :3, 3]).sum(dim=0)
    return mean, _covariance_of_residuals(d_rot, poses, mean, w)


def _covariance_of_residuals(d_rot: torch.Tensor, poses: torch.Tensor, mean: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(6, 6) ``Σ w_i r_i r_iᵀ`` with ``r_i = (d_rot_i, R̄ᵀ (t_i - t̄))``."""
    d_trans = (poses[:, :3, 3] - mean[:3, 3]) @ mean[:3, :3]
    residual = torch.cat((d_rot, d_trans), dim=-1)
    return (w[:, None] * residual).T @ residual


def tangent_residuals(poses: torch.Tensor, mean: torch.Tensor) -> torch.Tensor:
    """(N, 6) residuals ``(Log(R̄ᵀ R_i), R̄ᵀ (t_i - t̄))`` of poses (N, 4, 4) about ``mean`` (4, 4): rotation first."""
    return torch.cat((so3_log(mean[:3, :3].transpose(0, 1) @ poses[:, :3, :3]), (poses[:, :3, 3] - mean[:3, 3]) @ mean[:3, :3]), dim=-1)


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
    residual = tangent_residuals(poses, mean)
    return (w[:, None] * residual).T @ residual
