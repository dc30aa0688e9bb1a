"""The sensor data of a tracking run: true camera path, drifting odometry, images, an optional kidnapping.

Everything lives on the odometry grid ``t_k = k / odom_rate``; images are taken at a subset of
those stamps, so an image and the odometry message of its stamp describe the same instant. Two
sources of a camera path exist:

- :class:`WorldPath`: the figure-eight of :mod:`locnerf.sim` in the procedural world, images
  rendered at the true pose with the simulated camera noise;
- :class:`SequencePath`: a posed image sequence (e.g. the lego test orbit). Frame ``j`` gets the
  stamp ``j · Δ``, where ``Δ`` is the mean distance between consecutive frames divided by the
  nominal speed, rounded to a whole number of odometry periods (so every frame lies on the grid);
  between frames the pose follows the SE(3) geodesic. The sequence is treated as a closed loop.

A kidnapping at ``t*`` makes the true path jump about half a loop ahead (``τ(t) = t + shift``
from then on, ``shift`` = the path's ``kidnap_shift``). The odometry does not see the jump: its increment across ``t*`` is the motion the
camera would have made without it, every other increment is the true one (then drift and noise
are applied by :func:`locnerf.sim.sensors.simulate_odometry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data import PosedImages
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import pose_inverse, se3_exp, se3_log
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.sensors import CameraConfig, VioConfig, observe_image, simulate_odometry
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld


class CameraPath(Protocol):
    """A closed camera path with an image for every pose the run asks for."""

    @property
    def duration(self) -> float:
        """Length of one loop, seconds."""

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        """The camera of the images."""

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        """True ``T_world_cam`` (N, 4, 4) float64, metric data-set frame, at times (N,) seconds."""

    @property
    def kidnap_shift(self) -> float:
        """How far along the path (seconds) a kidnapping moves the camera: about half a loop."""

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        """(I,) float64 stamps on the odometry grid where images are taken, about ``rate`` per second."""

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Image (H, W, 3) float32 in [0, 1] seen at path time ``time`` from ``pose`` (4, 4)."""


def _grid_times(rate: float, odom_rate: float, duration: float) -> torch.Tensor:
    """Stamps about ``rate`` per second, each rounded to the odometry grid, without repeats."""
    count = math.floor(duration * rate + 1e-9) + 1
    ticks = torch.round(torch.arange(count, dtype=torch.float64) / rate * odom_rate)
    return torch.unique(ticks) / odom_rate


class WorldPath:
    """The figure-eight through the procedural world (camera = body)."""

    def __init__(self, world: ProceduralWorld, trajectory: FigureEightTrajectory, camera: CameraConfig) -> None:
        self.world = world
        self.trajectory = trajectory
        self.camera = camera

    @property
    def duration(self) -> float:
        return self.trajectory.duration

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        return self.world.default_intrinsics

    @property
    def kidnap_shift(self) -> float:
        return self.trajectory.duration / 2

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        return self.trajectory.poses_at(times)

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        return _grid_times(rate, odom_rate, duration)

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        return observe_image(self.world.render_image, pose, time, self.intrinsics, self.camera, generator)


class SequencePath:
    """A posed image sequence replayed as a closed loop at a nominal speed.

    Args:
        frames: the sequence's images and poses (map frame of its data set, metric).
        speed: nominal camera speed, data-set units per second.
        odom_rate: odometry rate, Hz; frame stamps are whole multiples of its period.
    """

    def __init__(self, frames: PosedImages, speed: float, odom_rate: float) -> None:
        if len(frames) < 2:
            raise ValueError(f"{frames.source}: {len(frames)} frame(s), expected at least 2 to follow a path")
        if speed <= 0:
            raise ValueError(f"speed {speed}: expected a positive nominal speed (units per second)")
        self.frames = frames
        poses = frames.T_world_cam.double()
        steps = (poses[1:, :3, 3] - poses[:-1, :3, 3]).norm(dim=-1)
        self.ticks_per_frame = max(1, round(float(steps.mean()) / speed * odom_rate))
        self.frame_period = self.ticks_per_frame / odom_rate
        closed = torch.cat([poses, poses[:1]])
        self._tangents = se3_log(pose_inverse(closed[:-1]) @ closed[1:])  # (K, 6) frame j -> j + 1

    @property
    def duration(self) -> float:
        return len(self.frames) * self.frame_period

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        return self.frames.intrinsics

    @property
    def kidnap_shift(self) -> float:
        return (len(self.frames) // 2) * self.frame_period

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        phase = torch.remainder(torch.as_tensor(times, dtype=torch.float64) / self.frame_period, len(self.frames))
        index = phase.floor().long().clamp(max=len(self.frames) - 1)
        fraction = (phase - index)[:, None]
        return self.frames.T_world_cam.double()[index] @ se3_exp(fraction * self._tangents[index])

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        stride = max(1, round(1.0 / (rate * self.frame_period)))
        count = math.floor(duration / (stride * self.frame_period) + 1e-9) + 1
        return torch.arange(count, dtype=torch.float64) * stride * self.frame_period

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        phase = time / self.frame_period
        index = round(phase)
        if abs(phase - index) > 1e-6:
            raise ValueError(f"image time {time} s is between frames (period {self.frame_period} s): expected a frame stamp")
        return self.frames.images[index % len(self.frames)]


class ScenarioConfig(BaseModel):
    """Rates, odometry errors and the kidnapping of a tracking run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    duration: float | None = Field(None, gt=0, description="Length of the run, seconds; None: one loop of the path.")
    image_rate: float = Field(3.0, gt=0, description="Images per second (rounded onto the odometry grid or the frames).")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry rate, drift and noise (metres, radians).")
    kidnap_at: float | None = Field(None, gt=0, description="Time of the kidnapping, seconds; None: no kidnapping.")
    seed: int = Field(0, description="Seed of the odometry and image noise.")


@dataclass(frozen=True)
class TrackingScenario:
    """A tracking run's data on the odometry grid.

    Attributes:
        stamps: (K,) float64 odometry stamps, seconds.
        truth: (K, 4, 4) float64 true ``T_world_cam`` in the map frame.
        odometry: (K, 4, 4) float64 ``T_odom_cam``, metric.
        image_ticks: odometry indices at which an image is taken, increasing.
        kidnap_tick: odometry index of the first pose after the jump, or None.
        path_times: (K,) float64 time along the path at each stamp (jumps at the kidnapping).
        path: where the poses and images come from.
    """

    stamps: torch.Tensor
    truth: torch.Tensor
    odometry: torch.Tensor
    image_ticks: list[int]
    kidnap_tick: int | None
    path_times: torch.Tensor
    path: CameraPath

    def image(self, tick: int, generator: torch.Generator) -> torch.Tensor:
        """The image (H, W, 3) taken at odometry index ``tick``."""
        metric_pose = self.path.poses_at(self.path_times[tick : tick + 1])[0]
        return self.path.image_at(float(self.path_times[tick]), metric_pose, generator)


def build_scenario(path: CameraPath, config: ScenarioConfig, normalization: MapNormalization) -> TrackingScenario:
    """Sample the path on the odometry grid, apply the kidnapping, simulate the odometry."""
    odom_rate = config.vio.rate
    if config.image_rate > odom_rate:
        raise ValueError(f"image rate {config.image_rate} Hz above the odometry rate {odom_rate} Hz: expected image_rate <= odom_rate")
    duration = config.duration if config.duration is not None else path.duration
    if config.kidnap_at is not None and config.kidnap_at >= duration:
        raise ValueError(f"kidnap_at {config.kidnap_at} s: expected a time inside the run (0, {duration}) s")
    count = math.floor(duration * odom_rate + 1e-9) + 1
    stamps = torch.arange(count, dtype=torch.float64) / odom_rate
    path_times = stamps.clone()
    kidnap_tick = None
    if config.kidnap_at is not None:
        kidnap_tick = max(1, math.ceil(config.kidnap_at * odom_rate - 1e-9))
        path_times[kidnap_tick:] += path.kidnap_shift
    metric = path.poses_at(path_times)
    perceived = metric.clone()
    if kidnap_tick is not None:
        unseen = path.poses_at(stamps[kidnap_tick - 1 : kidnap_tick + 1])
        step = pose_inverse(unseen[0]) @ unseen[1]
        perceived[kidnap_tick:] = perceived[kidnap_tick - 1] @ step @ pose_inverse(metric[kidnap_tick]) @ metric[kidnap_tick:]
    generator = torch.Generator().manual_seed(config.seed)
    odometry = simulate_odometry(perceived, config.vio, generator)
    image_times = path.image_times(config.image_rate, odom_rate, duration)
    image_ticks = sorted({round(float(t) * odom_rate) for t in image_times if round(float(t) * odom_rate) < count})
    return TrackingScenario(stamps, normalization.metric_to_map(metric), odometry, image_ticks, kidnap_tick, path_times, path)
