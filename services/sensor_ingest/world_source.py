"""The procedural world as a sensor: the simulator of :mod:`locnerf.sim` along the figure-eight.

A thin adapter: the odometry, camera and timing models are those of the offline tracking
evaluation (:func:`locnerf.sim.stream.simulated_events`); this module only names the stream's
configuration. The body carries the camera at ``camera.T_body_cam`` (identity: the body is the
camera); stamps are trajectory seconds from 0.
"""

from __future__ import annotations

from collections.abc import Iterator

from pydantic import BaseModel, ConfigDict, Field

from locnerf.sim.events import SensorEvent
from locnerf.sim.paths import WorldPath
from locnerf.sim.scenario import ScenarioConfig
from locnerf.sim.sensors import CameraConfig, VioConfig
from locnerf.sim.stream import simulated_events
from locnerf.sim.trajectory import FigureEightTrajectory, TrajectoryConfig
from locnerf.sim.world import ProceduralWorld


class WorldSourceConfig(BaseModel):
    """The synthetic stream: duration, rates, noise."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    duration: float = Field(60.0, gt=0, description="Length of the stream, seconds of sensor time.")
    image_rate: float = Field(5.0, ge=0, description="Camera frames per second, on the odometry grid (0: odometry only).")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry (and ground-truth) rate, drift and noise.")
    camera: CameraConfig = Field(default_factory=CameraConfig, description="Frame noise, exposure gain and mounting.")
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig, description="Path of the body.")
    distinct_frames: int = Field(
        0,
        ge=0,
        description="Render only the first N frames and send them again in turn (0: render every frame). An overload test "
        "uses it to send images faster than the renderer could; the images then no longer match the poses.",
    )


def world_events(world: ProceduralWorld, config: WorldSourceConfig, seed: int) -> Iterator[SensorEvent]:
    """Time-ordered ground truth, odometry (same stamps, truth first) and image events of the world."""
    path = WorldPath(world, FigureEightTrajectory(config.trajectory), config.camera)
    run = ScenarioConfig(duration=config.duration, image_rate=config.image_rate, vio=config.vio, seed=seed)
    return simulated_events(path, run, config.distinct_frames)
