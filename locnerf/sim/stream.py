"""A time-ordered stream of synthetic sensor events: drifting odometry and noisy images.

Odometry is computed for the whole run up front (it is cheap); images are rendered lazily while
iterating. At equal stamps an odometry event comes before the image event.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.sensors import CameraConfig, VioConfig, observe_image, simulate_odometry
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld


@dataclass(frozen=True)
class OdometryEvent:
    """One VIO message: ``T_odom_body`` (4, 4) float64 and the true ``T_world_body`` (4, 4) for evaluation."""

    stamp: float
    T_odom_body: torch.Tensor
    T_world_body: torch.Tensor


@dataclass(frozen=True)
class ImageEvent:
    """One camera image (H, W, 3) float32 in [0, 1], its intrinsics and the true ``T_world_cam`` (4, 4)."""

    stamp: float
    image: torch.Tensor
    intrinsics: PinholeIntrinsics
    T_world_cam: torch.Tensor


class SyntheticStreamConfig(BaseModel):
    """What the synthetic run records and for how long."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    seed: int = Field(0, description="Seed of the odometry and image noise.")
    duration: float | None = Field(None, gt=0, description="Length of the run, seconds; None: one loop of the trajectory.")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry rate and drift.")
    camera: CameraConfig = Field(default_factory=CameraConfig, description="Camera rate, noise and extrinsic.")


class SyntheticStream:
    """Iterate a synthetic run's events in time order.

    Args:
        world: the scene the camera sees.
        trajectory: the true body path.
        config: rates, noise and seed.
        intrinsics: camera model; None: ``world.default_intrinsics``.
    """

    def __init__(
        self,
        world: ProceduralWorld,
        trajectory: FigureEightTrajectory,
        config: SyntheticStreamConfig | None = None,
        intrinsics: PinholeIntrinsics | None = None,
    ) -> None:
        self.world = world
        self.trajectory = trajectory
        self.config = config or SyntheticStreamConfig()
        self.intrinsics = intrinsics or world.default_intrinsics
        self.duration = self.config.duration if self.config.duration is not None else trajectory.duration
        self.T_body_cam = torch.tensor(self.config.camera.T_body_cam, dtype=torch.float64)
        validate_poses(self.T_body_cam, name="camera.T_body_cam")

    def _stamps(self, rate: float) -> torch.Tensor:
        """Stamps k / rate for k = 0, 1, ... up to the duration (inclusive), float64 (K,)."""
        count = math.floor(self.duration * rate + 1e-9) + 1
        return torch.arange(count, dtype=torch.float64) / rate

    def __iter__(self) -> Iterator[OdometryEvent | ImageEvent]:
        generator = torch.Generator().manual_seed(self.config.seed)
        odom_stamps = self._stamps(self.config.vio.rate)
        truth = self.trajectory.poses_at(odom_stamps)
        odometry = simulate_odometry(truth, self.config.vio, generator)
        image_stamps = self._stamps(self.config.camera.rate).tolist()
        next_image = 0
        for stamp, T_odom_body, T_world_body in zip(odom_stamps.tolist(), odometry, truth):
            while next_image < len(image_stamps) and image_stamps[next_image] < stamp:
                yield self._image(image_stamps[next_image], generator)
                next_image += 1
            yield OdometryEvent(stamp, T_odom_body, T_world_body)
        for image_stamp in image_stamps[next_image:]:
            yield self._image(image_stamp, generator)

    def _image(self, stamp: float, generator: torch.Generator) -> ImageEvent:
        T_world_cam = self.trajectory.pose_at(stamp) @ self.T_body_cam
        image = observe_image(self.world.render_image, T_world_cam, stamp, self.intrinsics, self.config.camera, generator)
        return ImageEvent(stamp, image, self.intrinsics, T_world_cam)
