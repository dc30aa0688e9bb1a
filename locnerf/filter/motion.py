"""Motion model (the paper's eq. 4): ``X_t = X_{t-1} · O_t · Exp(δ)``, ``δ ~ N(0, diag(σ_R², σ_t²))``.

``O_t`` is the odometry increment ``T_prev_curr`` of the camera (map units), right-multiplied so it
acts in each particle's own body frame; δ is drawn independently per particle, rotation part first.
With no odometry (a static image, the iNeRF protocol) only the noise is applied.
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

from locnerf.geometry.se3 import se3_exp

Triple = tuple[float, float, float]


class MotionNoiseConfig(BaseModel):
    """Standard deviations of the prediction noise δ, per axis of the camera frame."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    rotation_sigma: Triple = Field(
        (0.02, 0.02, 0.02), description="σ_R per rotation axis (x, y, z of the camera), radians."
    )
    translation_sigma: Triple = Field(
        (0.01, 0.01, 0.01), description="σ_t per translation axis (x, y, z of the camera), map units."
    )

    @field_validator("rotation_sigma", "translation_sigma")
    @classmethod
    def _non_negative(cls, value: Triple) -> Triple:
        if any(not (v >= 0.0) or v == float("inf") for v in value):
            raise ValueError(f"{value}: expected three finite non-negative standard deviations")
        return value

    def sigma_vector(self, scale: float = 1.0) -> torch.Tensor:
        """(6,) float64 standard deviations (rotation, translation), multiplied by ``scale``."""
        return torch.tensor(self.rotation_sigma + self.translation_sigma, dtype=torch.float64) * scale


def sample_tangent_noise(count: int, sigma: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """δ ~ N(0, diag(sigma²)): (count, 6) float64 tangent vectors, rotation part first."""
    return torch.randn(count, 6, dtype=torch.float64, generator=generator) * sigma


def propagate_poses(
    poses: torch.Tensor,
    odometry: torch.Tensor | None,
    sigma: torch.Tensor,
    generator: torch.Generator,
) -> torch.Tensor:
    """Apply eq. 4 to every particle at once.

    Args:
        poses: (N, 4, 4) particle poses ``T_world_cam``.
        odometry: (4, 4) increment ``T_prev_curr`` in map units, or None for noise only.
        sigma: (6,) noise standard deviations (rotation, translation).
        generator: CPU generator for the noise draws.
    Returns:
        (N, 4, 4) moved poses, same dtype/device as ``poses``.
    """
    moved = poses if odometry is None else poses @ odometry.to(poses.dtype).to(poses.device)
    if float(sigma.abs().max()) == 0.0:
        return moved.clone()
    delta = sample_tangent_noise(poses.shape[0], sigma, generator)
    return moved @ se3_exp(delta).to(poses.dtype).to(poses.device)
