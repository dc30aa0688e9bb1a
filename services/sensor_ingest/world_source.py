"""The procedural world as a sensor: a camera flown along a figure-eight with VIO-like odometry."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.sim.trajectory import FigureEightTrajectory, TrajectoryConfig
from locnerf.sim.world import ProceduralWorld
from services.sensor_ingest.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent
from services.sensor_ingest.synthetic_odometry import OdometryNoiseConfig, SyntheticOdometry


class CameraNoiseConfig(BaseModel):
    """Photometric corruption of the rendered frames."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pixel_noise: float = Field(0.01, ge=0, description="σ of additive Gaussian noise on [0, 1] colours.")
    exposure_amplitude: float = Field(0.05, ge=0, lt=1, description="Relative amplitude of a slow exposure (gain) oscillation.")
    exposure_period: float = Field(20.0, gt=0, description="Period of the exposure oscillation, seconds.")


class WorldSourceConfig(BaseModel):
    """The synthetic stream: rates, duration, noise."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    odometry_rate: float = Field(15.0, gt=0, description="Odometry (and ground-truth) messages per second.")
    camera_rate: float = Field(5.0, gt=0, description="Camera frames per second.")
    duration: float = Field(60.0, gt=0, description="Length of the stream, seconds of sensor time.")
    start_time: float = Field(0.0, description="Trajectory time of the first event, seconds.")
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig, description="Path of the camera.")
    odometry: OdometryNoiseConfig = Field(default_factory=OdometryNoiseConfig, description="VIO noise and drift.")
    camera: CameraNoiseConfig = Field(default_factory=CameraNoiseConfig, description="Frame noise and exposure change.")
    distinct_frames: int = Field(
        0,
        ge=0,
        description="Render only the first N frames and send them again in turn (0: render every frame). An overload test "
        "uses it to send images faster than the renderer could; the images then no longer match the poses.",
    )


def _frame(world: ProceduralWorld, pose: torch.Tensor, stamp: float, camera: CameraNoiseConfig, generator: torch.Generator) -> np.ndarray:
    """Rendered RGB (H, W, 3) uint8 with exposure gain and pixel noise."""
    image = world.render_image(pose.to(world.device, torch.float32)).float().cpu()
    gain = 1.0 + camera.exposure_amplitude * math.sin(2 * math.pi * stamp / camera.exposure_period)
    noisy = image * gain + camera.pixel_noise * torch.randn(image.shape, generator=generator)
    return (noisy.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()


def world_events(world: ProceduralWorld, config: WorldSourceConfig, generator: torch.Generator) -> Iterator[SensorEvent]:
    """Time-ordered ground truth and odometry (same stamps, truth first) and image events.

    Every frame is rendered at its pose, unless ``config.distinct_frames`` caps the rendered ones.
    The body frame is the camera frame (OpenGL axes); stamps are trajectory seconds.
    """
    trajectory = FigureEightTrajectory(config.trajectory)
    odometry = SyntheticOdometry(config.odometry, generator)
    odometry_period, camera_period = 1.0 / config.odometry_rate, 1.0 / config.camera_rate
    odometry_count = int(config.duration * config.odometry_rate)
    camera_count = int(config.duration * config.camera_rate)
    stamps = [(config.start_time + i * odometry_period, 0) for i in range(odometry_count)]
    stamps += [(config.start_time + i * camera_period, 1) for i in range(camera_count)]
    reused: list[np.ndarray] = []  # the first distinct_frames frames, when they are sent again
    for stamp, is_camera in sorted(stamps):
        pose = trajectory.pose_at(stamp)
        if is_camera:
            if config.distinct_frames and len(reused) == config.distinct_frames:
                pixels = reused[round(stamp * config.camera_rate) % len(reused)]
            else:
                pixels = _frame(world, pose, stamp, config.camera, generator)
                if config.distinct_frames:
                    reused.append(pixels)
            yield ImageEvent(stamp, pixels, world.default_intrinsics)
        else:
            yield GroundTruthEvent(stamp, pose)
            yield OdometryEvent(stamp, odometry.step(stamp, pose))
