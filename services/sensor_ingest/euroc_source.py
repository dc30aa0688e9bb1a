"""A EuRoC MAV folder as the sensor stream: its camera frames at their own stamps, odometry at 15 Hz.

Images keep their EuRoC stamps (seconds since the epoch) and are undistorted with the camera's
radial-tangential model (grey frames become three equal channels). locnerf runs no VIO of its own,
so the odometry is synthesised from the ground-truth trajectory (interpolated geodesically) with the
simulated VIO of :func:`locnerf.sim.sensors.simulate_odometry` (the evaluation's model): of the
camera (body pose · ``T_BS``) by default, or of the body (IMU) frame, as a real VIO reports it, with ``odometry_frame = "body"``;
the filter then needs ``loop.T_body_cam`` = :func:`euroc_T_body_cam`. The ground truth (camera) is
published beside it. IMU samples are not read. Only frames inside the ground
truth's time span are sent.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.euroc import EurocCamera, EurocSequence
from locnerf.errors import DatasetError
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.geometry.se3 import interpolate_pose, pose_inverse
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent
from locnerf.sim.sensors import VioConfig, simulate_odometry


class EurocSourceConfig(BaseModel):
    """Which EuRoC folder to stream and how."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: str = Field("", description="Folder holding mav0/ (the EuRoC ASL layout).")
    camera: str = Field("cam0", description="Camera folder under mav0/.")
    groundtruth: str = Field("", description="Ground-truth file (ASL data.csv or TUM .txt); empty: found in the folder.")
    downscale: float = Field(1.0, ge=1, description="Image size divisor (area resize after undistortion).")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry (and ground-truth) rate, drift and noise.")
    odometry_frame: Literal["camera", "body"] = Field(
        "camera",
        description="Frame whose motion the odometry reports: the camera (the filter's T_body_cam is identity) "
        "or the body/IMU as a VIO does (set the filter's loop.T_body_cam to euroc_T_body_cam, i.e. T_BS in OpenGL axes).",
    )


def euroc_T_body_cam(camera: EurocCamera) -> torch.Tensor:
    """(4, 4) float64 pose of the camera in locnerf's OpenGL axes in the body frame: ``T_BS`` converted,
    the value of the filter's ``loop.T_body_cam`` for body odometry."""
    return opencv_to_opengl(camera.T_body_cam)


def camera_trajectory_at(sequence: EurocSequence, stamps: np.ndarray) -> torch.Tensor:
    """Ground-truth camera poses (S, 4, 4) float64, OpenGL camera axes, at stamps inside the truth's span."""
    truth = sequence.truth_stamps
    after = np.clip(np.searchsorted(truth, stamps, side="right"), 1, len(truth) - 1)
    poses = []
    for stamp, index in zip(stamps, after):
        fraction = (stamp - truth[index - 1]) / (truth[index] - truth[index - 1])
        body = interpolate_pose(sequence.T_world_body[index - 1], sequence.T_world_body[index], float(fraction))
        poses.append(body @ sequence.camera.T_body_cam)
    return opencv_to_opengl(torch.stack(poses))


def euroc_events(sequence: EurocSequence, config: EurocSourceConfig, generator: torch.Generator) -> Iterator[SensorEvent]:
    """Time-ordered ground truth and odometry (same stamps, truth first) and image events."""
    begin = max(sequence.truth_stamps[0], sequence.image_stamps[0])
    end = min(sequence.truth_stamps[-1], sequence.image_stamps[-1])
    period = 1.0 / config.vio.rate
    odometry_stamps = begin + period * np.arange(int(math.floor((end - begin) / period)) + 1)
    frames = np.flatnonzero((sequence.image_stamps >= begin) & (sequence.image_stamps <= end))
    if len(frames) == 0:
        raise DatasetError(f"{sequence.root}: no image lies inside the ground truth's time span")
    truth = camera_trajectory_at(sequence, odometry_stamps)
    moving = truth if config.odometry_frame == "camera" else truth @ pose_inverse(euroc_T_body_cam(sequence.camera))
    intrinsics = sequence.camera.intrinsics.scaled(1.0 / config.downscale)
    odometry = simulate_odometry(moving, config.vio, generator)
    timeline = sorted([(float(s), 0, i) for i, s in enumerate(odometry_stamps)] + [(float(sequence.image_stamps[k]), 1, int(k)) for k in frames])
    for stamp, is_frame, index in timeline:
        if is_frame:
            yield ImageEvent(stamp, sequence.read_image(index, config.downscale), intrinsics)
            continue
        yield GroundTruthEvent(stamp, truth[index])
        yield OdometryEvent(stamp, odometry[index])
