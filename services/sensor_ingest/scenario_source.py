"""The offline tracking experiment's sensor data as a stream: the same scenario, served live.

``locnerf eval tracking`` builds a :class:`~locnerf.sim.scenario.TrackingScenario` (true path on
the odometry grid, drifting VIO, images on the grid, optional kidnapping). This source streams that
very scenario from the same configuration and seed (:func:`locnerf.sim.stream.simulated_events`),
so the live run (``locnerf eval tracking --live``) and the offline run see identical odometry,
images and truth; there is no second noise model here.

Two paths: ``sequence = "world"`` (the procedural world's figure-eight, images rendered with the
simulated camera) or a data-set folder read by :func:`locnerf.data.read_dataset` (e.g. the lego
test orbit, or any posed sequence the generic reader knows), replayed as a closed loop at a nominal
speed. The camera is the body (``T_body_cam = I``).
"""

from __future__ import annotations

from collections.abc import Iterator

from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.colour_camera import ColourCameraSetting, colour_camera_matrix
from locnerf.sim.events import SensorEvent
from locnerf.sim.paths import CameraPath, WorldPath, read_sequence_path
from locnerf.sim.scenario import ScenarioConfig
from locnerf.sim.sensors import CameraConfig, VioConfig
from locnerf.sim.stream import simulated_events
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld

WORLD = "world"


class ScenarioSourceConfig(BaseModel):
    """Which path to follow and the scenario's rates, odometry errors and kidnapping (as offline)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    sequence: str = Field(WORLD, description="'world' (figure-eight in the procedural world) or a data-set folder (locnerf.data.read_dataset).")
    split: str = Field("test", description="Data-set folder: the split to replay.")
    downscale: int | None = Field(None, ge=1, description="Data-set folder: image size divisor (None: the reader's default).")
    speed: float = Field(0.66, gt=0, description="Data-set folder: nominal camera speed, metres per second.")
    frame_rate: float | None = Field(
        None, gt=0, description="Data-set folder: the capture's frame rate, Hz, to replay at its real speed (instead of speed); a multiple of vio.rate."
    )
    duration: float | None = Field(None, gt=0, description="Seconds of sensor time; None: one loop of the path.")
    image_rate: float = Field(5.0, gt=0, description="Images per second (rounded onto the odometry grid or the frames).")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry rate, drift and noise (the offline path's model).")
    kidnap_at: float | None = Field(None, gt=0, description="Seconds: the camera jumps about half a loop ahead, unseen by the odometry.")
    T_depth_colour: ColourCameraSetting


def camera_path(config: ScenarioSourceConfig) -> CameraPath:
    """The figure-eight of the default procedural world, or the data-set folder's frames in metres."""
    if config.sequence == WORLD:
        return WorldPath(ProceduralWorld.default(), FigureEightTrajectory(), CameraConfig())
    colour_camera = None if config.T_depth_colour is None else colour_camera_matrix(config.T_depth_colour)
    return read_sequence_path(
        config.sequence, config.split, config.downscale, config.speed, config.vio.rate, frame_rate=config.frame_rate, T_depth_colour=colour_camera
    )


def scenario_events(config: ScenarioSourceConfig, seed: int) -> Iterator[SensorEvent]:
    """The offline scenario's events, truth in the metric world frame (what the wire carries)."""
    run = ScenarioConfig(duration=config.duration, image_rate=config.image_rate, vio=config.vio, kidnap_at=config.kidnap_at, seed=seed)
    return simulated_events(camera_path(config), run)
