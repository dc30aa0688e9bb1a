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

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.colour_camera import ColourCameraSetting, colour_camera_matrix
from locnerf.data.map_lens import MapLens
from locnerf.data.sfm_poses import PoseSource
from locnerf.errors import LocnerfInputError
from locnerf.odometry.sequence import RGBD, RGBD_ONLINE, SYNTHETIC, OdometrySourceConfig, RecordedReplay, sequence_rgbd_frames, sequence_track
from locnerf.odometry.tracks import OdometryTrack
from locnerf.sim.events import GroundTruthEvent, RgbdFrameEvent, SensorEvent
from locnerf.sim.paths import CameraPath, SequencePath, WorldPath, read_sequence_path
from locnerf.sim.scenario import ScenarioConfig, run_times
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
    kidnap_at: float | None = Field(None, gt=0, description="Seconds: the camera jumps ahead along the path, unseen by the odometry.")
    kidnap_shift: float | None = Field(None, gt=0, description="Seconds along the path the kidnapping jumps (as offline); None: about half a loop.")
    T_depth_colour: ColourCameraSetting
    lens: MapLens | None = Field(
        None,
        description="The lens an SfM map records (its metadata) and the map's camera: the replayed colour images are resampled through it, as the map's queries are.",
    )
    passes: int = Field(1, ge=1, description="Data-set folder: replay the frames this many times, forward and backward in turn.")
    poses: PoseSource = Field("dslam", description="7-Scenes folder: the ground truth, dslam (its pose files) or sfm (pgt_sfm/); the map's.")
    odometry: OdometrySourceConfig = Field(
        default_factory=OdometrySourceConfig,
        description="Data-set folder: the simulator's odometry, RGB-D odometry computed from the frames, or a trajectory file.",
    )


def camera_path(config: ScenarioSourceConfig) -> CameraPath:
    """The figure-eight of the default procedural world, or the data-set folder's frames in metres."""
    if config.sequence == WORLD:
        return WorldPath(ProceduralWorld.default(), FigureEightTrajectory(), CameraConfig())
    return read_sequence_path(
        config.sequence,
        config.split,
        config.downscale,
        config.speed,
        config.vio.rate,
        frame_rate=config.frame_rate,
        T_depth_colour=_colour_camera(config),
        passes=config.passes,
        poses=config.poses,
        lens=config.lens,
    )


def _colour_camera(config: ScenarioSourceConfig) -> torch.Tensor | None:
    return None if config.T_depth_colour is None else colour_camera_matrix(config.T_depth_colour)


def scenario_events(config: ScenarioSourceConfig, seed: int, online_rgbd: bool = False) -> Iterator[SensorEvent]:
    """The offline scenario's events, truth in the metric world frame (what the wire carries); the
    odometry is the simulator's, or real (``config.odometry``: computed here from the frames, or a file).
    With ``online_rgbd`` and RGB-D odometry, no odometry is computed here: every odometry stamp
    yields the camera's RGB-D frame (:class:`RgbdFrameEvent`, after its ground truth) for the
    ingest's online odometry (services/sensor_ingest/odometry_stage.py) to turn into odometry as it is released.

    Raises:
        LocnerfInputError: real odometry or several passes on the procedural world (it has no recorded frames).
    """
    run = ScenarioConfig(
        duration=config.duration, image_rate=config.image_rate, vio=config.vio, kidnap_at=config.kidnap_at, kidnap_shift=config.kidnap_shift, seed=seed
    )
    path = camera_path(config)
    if not isinstance(path, SequencePath):
        if config.odometry.source != SYNTHETIC or config.passes != 1:
            raise LocnerfInputError("sequence 'world': expected the synthetic odometry and one pass (real odometry needs recorded frames)")
        return simulated_events(path, run)
    stamps, path_times = run_times(path, run)
    replay = RecordedReplay(path, config.sequence, config.split, _colour_camera(config), config.passes)
    if online_rgbd and config.odometry.source == RGBD:
        frames = sequence_rgbd_frames(replay, stamps, path_times)
        none = OdometryTrack(
            torch.eye(4, dtype=torch.float64).repeat(len(stamps), 1, 1), torch.zeros(len(stamps), dtype=torch.bool), RGBD_ONLINE, from_camera=True
        )
        return _with_frames(simulated_events(path, run, track=none), frames)
    track = sequence_track(config.odometry, replay, stamps, path_times)
    return simulated_events(path, run, track=track)


def _with_frames(events: Iterator[SensorEvent], frames: Iterator[RgbdFrameEvent]) -> Iterator[SensorEvent]:
    """``events`` (a ground truth at every odometry stamp, no odometry) with each stamp's RGB-D frame after its ground truth."""
    for event in events:
        yield event
        if isinstance(event, GroundTruthEvent):
            yield next(frames)
