"""Replay of a posed image sequence (e.g. the lego test orbit) with odometry synthesised from its poses.

Frame k is stamped ``k / frame_rate``. Between frames the camera moves along the geodesic between
their poses; odometry (the simulated VIO of :func:`locnerf.sim.sensors.simulate_odometry`, the
evaluation's model) and ground truth are emitted at ``vio.rate`` along that path. Poses leave as
metric world-frame poses (the sequence's map-frame poses converted with its normalisation).
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.colour_camera import ColourCameraSetting
from locnerf.data.posed_images import PosedImages
from locnerf.data.sfm_poses import PoseSource
from locnerf.errors import DatasetError
from locnerf.geometry.se3 import interpolate_pose
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent, posed_depth_frame, rgb8
from locnerf.sim.sensors import VioConfig, simulate_odometry


class ReplaySourceConfig(BaseModel):
    """Which sequence to replay and at what rates."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: str = Field("", description="Data-set folder (LLFF, NeRF-synthetic, nerfstudio transforms.json).")
    split: str = Field("test", description="Split to replay: train, test, val or all (see locnerf.data.read_dataset).")
    downscale: int | None = Field(None, ge=1, description="Image size divisor (None: the reader's default).")
    skip_missing: bool = Field(False, description="NeRF-synthetic: leave out frames whose image file is absent.")
    frame_rate: float = Field(5.0, gt=0, description="Frames per second of the replay.")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry (and ground-truth) rate, drift and noise.")
    T_depth_colour: ColourCameraSetting
    poses: PoseSource = Field("dslam", description="7-Scenes folder: the ground truth, dslam (its pose files) or sfm (pgt_sfm/); the map's.")


def replay_events(sequence: PosedImages, config: ReplaySourceConfig, generator: torch.Generator) -> Iterator[SensorEvent]:
    """Time-ordered ground truth and odometry (same stamps, truth first) and image events."""
    if len(sequence) < 2:
        raise DatasetError(f"{sequence.source}: a replay needs at least 2 frames, got {len(sequence)}")
    poses = sequence.normalization.map_to_metric(sequence.T_world_cam.double())
    end = (len(sequence) - 1) / config.frame_rate
    odometry_stamps = [i / config.vio.rate for i in range(int(end * config.vio.rate) + 1)]
    truth = torch.stack([_pose_along(poses, stamp * config.frame_rate) for stamp in odometry_stamps])
    odometry = simulate_odometry(truth, config.vio, generator)
    timeline = [(stamp, 0, i) for i, stamp in enumerate(odometry_stamps)] + [(k / config.frame_rate, 1, k) for k in range(len(sequence))]
    for stamp, is_frame, index in sorted(timeline):
        if is_frame:
            yield ImageEvent(stamp, rgb8(sequence.images[index]), sequence.intrinsics, posed_depth_frame(sequence, index))
            continue
        yield GroundTruthEvent(stamp, truth[index])
        yield OdometryEvent(stamp, odometry[index])


def _pose_along(poses: torch.Tensor, position: float) -> torch.Tensor:
    """The pose (4, 4) at fractional frame index ``position`` on the geodesics between poses (N, 4, 4)."""
    position = min(position, len(poses) - 1.0)
    index = min(int(position), len(poses) - 2)
    return interpolate_pose(poses[index], poses[index + 1], position - index)
