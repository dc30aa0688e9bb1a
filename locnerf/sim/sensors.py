"""Simulated sensors along a trajectory: drifting visual-inertial odometry and a noisy camera.

VIO model, per increment k (stamps ``t_k = t_0 + k / rate``), with the true body increment
``O_k = T_{k-1}⁻¹ T_k`` (rotation ``ΔR_k``, translation ``Δp_k``):

    Õ_k = [R_y(ω_yaw Δt) ΔR_k, (1 + s) Δp_k] · Exp(δ_k),   δ_k ~ N(0, diag(σ_R² I3, σ_t² I3))
    T_odom_body_k = T_odom_body_{k-1} · Õ_k,              T_odom_body_0 = T_world_body(t_0)

so the odometry frame coincides with the world at the first stamp and then drifts: a scale error
``s`` of the distance travelled, a yaw drift ``ω_yaw`` about the body's up (y) axis, and white
noise on every increment (tangent order: rotation first, as everywhere in locnerf). A long run is
simulated piece by piece: each piece starts from the odometry pose where the previous one ended.

Camera model: the clean render times an exposure gain ``1 + a·sin(2π t / period)`` plus white
Gaussian noise on every channel, clamped to [0, 1]. This is the one sensor model of locnerf: the
offline tracking evaluation, the live services' simulated sources and the load test use it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.se3 import make_pose, relative_pose, se3_exp
from locnerf.geometry.so3 import so3_exp
from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics


class VioConfig(BaseModel):
    """Rate and error model of the simulated visual-inertial odometry."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    rate: float = Field(15.0, gt=0, description="Odometry messages per second, Hz.")
    translation_drift: float = Field(0.01, gt=-1, description="Scale error s: each increment's translation is scaled by (1 + s).")
    yaw_drift_rate: float = Field(math.radians(0.2), description="Yaw drift about the body's up (y) axis, radians per second.")
    rotation_noise: float = Field(1e-3, ge=0, description="Std of the white rotation noise on each increment, radians per axis.")
    translation_noise: float = Field(2e-3, ge=0, description="Std of the white translation noise on each increment, metres per axis.")


def simulate_odometry(true_poses: torch.Tensor, config: VioConfig, generator: torch.Generator, start: torch.Tensor | None = None) -> torch.Tensor:
    """Drifting odometry ``T_odom_body`` (K, 4, 4) float64 from true body poses ``T_world_body`` (K, 4, 4) at the VIO rate.

    Args:
        start: (4, 4) odometry pose at the first true pose, to continue an earlier piece of the run;
            None: the first true pose (the odometry frame starts at the world frame).
    """
    validate_poses(true_poses, name="true_poses")
    if start is not None:
        validate_poses(start, name="start")
    if true_poses.ndim != 3 or true_poses.shape[0] < 1:
        raise ValueError(f"true_poses: expected shape (K, 4, 4) with K >= 1, got {tuple(true_poses.shape)}")
    poses = true_poses.double().cpu()
    increments = relative_pose(poses[:-1], poses[1:])  # (K-1, 4, 4)
    count = increments.shape[0]
    yaw = torch.zeros(count, 3, dtype=torch.float64)
    yaw[:, 1] = config.yaw_drift_rate / config.rate
    rotation = so3_exp(yaw) @ increments[:, :3, :3]
    translation = (1.0 + config.translation_drift) * increments[:, :3, 3]
    sigma = torch.tensor([config.rotation_noise] * 3 + [config.translation_noise] * 3, dtype=torch.float64)
    noise = se3_exp(torch.randn(count, 6, dtype=torch.float64, generator=generator) * sigma)
    drifted = make_pose(rotation, translation) @ noise
    odometry = [poses[0] if start is None else start.double().cpu()]
    for increment in drifted:
        odometry.append(odometry[-1] @ increment)
    return torch.stack(odometry)


class CameraConfig(BaseModel):
    """Noise, gain and mounting of the simulated camera (its image rate is the run's, see ScenarioConfig)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pixel_noise: float = Field(0.01, ge=0, description="Std of the white Gaussian noise added to every channel, in [0, 1] units.")
    gain_amplitude: float = Field(0.0, ge=0, lt=1, description="Amplitude of the global exposure gain drift: gain = 1 + a·sin(2π t / period).")
    gain_period: float = Field(20.0, gt=0, description="Period of the exposure gain drift, seconds.")
    T_body_cam: list[list[float]] = Field(
        default_factory=lambda: [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
        description="4×4 camera-to-body extrinsic (OpenGL camera axes); identity: the camera is the body.",
    )


def observe_image(
    render_image: Callable[[torch.Tensor, PinholeIntrinsics], torch.Tensor],
    T_world_cam: torch.Tensor,
    stamp: float,
    intrinsics: PinholeIntrinsics,
    config: CameraConfig,
    generator: torch.Generator,
) -> torch.Tensor:
    """A noisy, gain-drifted image (H, W, 3) float32 in [0, 1].

    Args:
        render_image: callable (T_world_cam (4, 4), intrinsics) -> (H, W, 3), e.g. ``ProceduralWorld.render_image``.
        T_world_cam: (4, 4) true camera pose.
        stamp: seconds, for the gain drift.
    """
    clean = render_image(T_world_cam, intrinsics).float().cpu()
    gain = 1.0 + config.gain_amplitude * math.sin(2 * math.pi * stamp / config.gain_period)
    noise = config.pixel_noise * torch.randn(clean.shape, dtype=torch.float32, generator=generator)
    return (gain * clean + noise).clamp(0.0, 1.0)
