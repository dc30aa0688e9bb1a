"""Replay of a posed image sequence (e.g. the lego test orbit) with odometry synthesised from its poses.

Frame k is stamped ``k / frame_rate``. Between frames the camera moves along the geodesic between
their poses; odometry (with the noise of :mod:`.synthetic_odometry`) and ground truth are emitted at
``odometry_rate`` along that path. Poses leave as metric world-frame poses (the sequence's map-frame
poses converted with its normalisation).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.posed_images import PosedImages
from locnerf.geometry.se3 import interpolate_pose
from services.sensor_ingest.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent
from services.sensor_ingest.synthetic_odometry import OdometryNoiseConfig, SyntheticOdometry


class ReplaySourceConfig(BaseModel):
    """Which sequence to replay and at what rates."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: str = Field("", description="Data-set folder (LLFF, NeRF-synthetic, nerfstudio transforms.json).")
    split: str = Field("test", description="Split to replay: train, test, val or all (see locnerf.data.read_dataset).")
    downscale: int | None = Field(None, ge=1, description="Image size divisor (None: the reader's default).")
    skip_missing: bool = Field(False, description="NeRF-synthetic: leave out frames whose image file is absent.")
    frame_rate: float = Field(5.0, gt=0, description="Frames per second of the replay.")
    odometry_rate: float = Field(15.0, gt=0, description="Odometry (and ground-truth) messages per second.")
    odometry: OdometryNoiseConfig = Field(default_factory=OdometryNoiseConfig, description="VIO noise and drift.")


def replay_events(sequence: PosedImages, config: ReplaySourceConfig, generator: torch.Generator) -> Iterator[SensorEvent]:
    """Time-ordered ground truth and odometry (same stamps, truth first) and image events."""
    if len(sequence) < 2:
        raise ValueError(f"{sequence.source}: a replay needs at least 2 frames, got {len(sequence)}")
    poses = sequence.normalization.map_to_metric(sequence.T_world_cam.double())
    odometry = SyntheticOdometry(config.odometry, generator)
    end = (len(sequence) - 1) / config.frame_rate
    stamps = [(i / config.odometry_rate, 0) for i in range(int(end * config.odometry_rate) + 1)]
    stamps += [(k / config.frame_rate, 1) for k in range(len(sequence))]
    for stamp, is_frame in sorted(stamps):
        if is_frame:
            index = round(stamp * config.frame_rate)
            pixels = (sequence.images[index].clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()
            yield ImageEvent(stamp, np.ascontiguousarray(pixels), sequence.intrinsics)
            continue
        position = min(stamp * config.frame_rate, len(sequence) - 1.0)
        index = min(int(position), len(sequence) - 2)
        pose = interpolate_pose(poses[index], poses[index + 1], position - index)
        yield GroundTruthEvent(stamp, pose)
        yield OdometryEvent(stamp, odometry.step(stamp, pose))
