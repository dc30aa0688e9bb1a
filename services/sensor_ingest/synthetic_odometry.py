"""VIO-like odometry synthesised from true poses: per-step noise and a steady yaw drift.

The odometry frame starts at the first true pose's body frame (``T_odom_body(0) = I``). Each step
integrates the true increment ``inv(T_k-1) T_k`` perturbed as ``Δ · Exp(δ_k)``, with
``δ_k ~ N(μ dt, diag(σ_R², σ_t²) dt)`` (rotation first) and μ a yaw-rate bias about the body's
up axis, so the error grows like a random walk plus a drift, as VIO does.
"""

from __future__ import annotations

import math

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.se3 import pose_inverse, se3_exp


class OdometryNoiseConfig(BaseModel):
    """Noise and drift of the synthetic odometry."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    rotation_noise: float = Field(0.005, ge=0, description="σ_R: rotation random walk, rad per √s.")
    translation_noise: float = Field(0.01, ge=0, description="σ_t: translation random walk, metres per √s.")
    yaw_drift: float = Field(math.radians(0.5), description="Yaw-rate bias about the body y axis, rad/s.")


class SyntheticOdometry:
    """Integrates noisy increments of a true trajectory.

    Args:
        config: noise and drift.
        generator: draws of δ_k.
    """

    def __init__(self, config: OdometryNoiseConfig, generator: torch.Generator) -> None:
        self.config = config
        self.generator = generator
        self._previous_truth: torch.Tensor | None = None
        self._previous_stamp = 0.0
        self.T_odom_body = torch.eye(4, dtype=torch.float64)

    def step(self, stamp: float, T_world_body: torch.Tensor) -> torch.Tensor:
        """The odometry pose (4, 4) float64 at ``stamp`` given the true pose (4, 4)."""
        truth = T_world_body.double()
        if self._previous_truth is not None:
            dt = stamp - self._previous_stamp
            if dt <= 0:
                raise ValueError(f"odometry stamps must increase: {stamp} after {self._previous_stamp}")
            c = self.config
            sigma = torch.tensor([c.rotation_noise] * 3 + [c.translation_noise] * 3, dtype=torch.float64) * math.sqrt(dt)
            delta = torch.randn(6, dtype=torch.float64, generator=self.generator) * sigma
            delta[1] += c.yaw_drift * dt
            increment = pose_inverse(self._previous_truth) @ truth
            self.T_odom_body = self.T_odom_body @ increment @ se3_exp(delta)
        self._previous_truth, self._previous_stamp = truth, stamp
        return self.T_odom_body.clone()
