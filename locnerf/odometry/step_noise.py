"""The per-step error of an odometry against a ground truth, as the filter's prediction noise sees it.

The motion model (:mod:`locnerf.filter.motion`) predicts ``X_t = X_{t-1} · O_t · Exp(δ)``: the
odometry's increment ``O_t`` corrected by a tangent δ in the camera's own frame. For a real odometry
the δ that makes the prediction exact is, step by step,

    ``δ_t = Log(O_t⁻¹ · G_t)``,  ``O_t = T_odom(t-1)⁻¹ T_odom(t)``,  ``G_t = T_truth(t-1)⁻¹ T_truth(t)``,

so the standard deviation of δ_t per axis (rotation first, radians; then translation, metres) is the
``rotation_sigma`` / ``translation_sigma`` that matches the prediction noise to the odometry. Only
steps between consecutive valid stamps count (a gap's longer step is widened by the filter itself).
Besides the standard deviation, :func:`step_noise` gives a robust one (1.4826 × the median absolute
deviation, insensitive to a few jumps) and the mean (a bias the noise cannot represent).
"""

from __future__ import annotations

from typing import Any

import torch

from locnerf.geometry.se3 import relative_pose, se3_log

MAD_TO_SIGMA = 1.4826
"""σ of a normal distribution per median absolute deviation."""


def step_errors(odometry: torch.Tensor, valid: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """δ_t of every step between consecutive valid stamps (module docstring).

    Args:
        odometry: (K, 4, 4) float64 ``T_odom_cam``, metres (ignored where not ``valid``).
        valid: (K,) bool.
        truth: (K, 4, 4) float64 true ``T_world_cam``, metres.
    Returns:
        (S, 6) float64 tangents (rotation rad, translation m), S the number of steps whose both ends are valid.
    Raises:
        ValueError: shapes that do not match, or no step with both ends valid.
    """
    if odometry.shape != truth.shape or odometry.shape[1:] != (4, 4) or valid.shape != odometry.shape[:1]:
        raise ValueError(f"odometry {tuple(odometry.shape)}, truth {tuple(truth.shape)}, valid {tuple(valid.shape)}: expected (K, 4, 4) twice and (K,)")
    pairs = valid[:-1] & valid[1:]
    if not bool(pairs.any()):
        raise ValueError("odometry step noise: no two consecutive valid stamps")
    odometry, truth = odometry.double(), truth.double()
    step_odometry = relative_pose(odometry[:-1], odometry[1:])[pairs]
    step_truth = relative_pose(truth[:-1], truth[1:])[pairs]
    return se3_log(relative_pose(step_odometry, step_truth))


def step_noise(odometry: torch.Tensor, valid: torch.Tensor, truth: torch.Tensor) -> dict[str, Any]:
    """Statistics of :func:`step_errors` per axis of the camera frame (x right, y up, z back).

    Returns:
        ``steps``; ``rotation_sigma`` / ``translation_sigma`` (standard deviations, rad / m),
        ``rotation_sigma_robust`` / ``translation_sigma_robust`` (1.4826 × MAD), ``rotation_mean`` /
        ``translation_mean``, each a list of three; ``translation_step_median`` (m) and
        ``rotation_step_median_deg``: the median size of a step's error.
    """
    errors = step_errors(odometry, valid, truth)
    std = errors.std(dim=0, unbiased=True) if len(errors) > 1 else torch.zeros(6, dtype=torch.float64)
    robust = MAD_TO_SIGMA * (errors - errors.median(dim=0).values).abs().median(dim=0).values
    mean = errors.mean(dim=0)
    return {
        "steps": len(errors),
        "rotation_sigma": std[:3].tolist(),
        "translation_sigma": std[3:].tolist(),
        "rotation_sigma_robust": robust[:3].tolist(),
        "translation_sigma_robust": robust[3:].tolist(),
        "rotation_mean": mean[:3].tolist(),
        "translation_mean": mean[3:].tolist(),
        "translation_step_median": float(errors[:, 3:].norm(dim=-1).median()),
        "rotation_step_median_deg": float(torch.rad2deg(errors[:, :3].norm(dim=-1).median())),
    }
