"""Odometry on a run's stamps from a real source: a recorded trajectory file, or RGB-D frames.

The simulator synthesises odometry from the ground truth (:mod:`locnerf.sim.sensors`); a track here
replaces it with what a camera measured. A track holds, at every odometry stamp of the run, the
camera's pose in the odometry frame (metres, OpenGL camera axes) or nothing (a gap: the file has no
sample near the stamp, or the RGB-D odometry failed on that frame). Its ``label`` says where it came
from, for every result: ``file:<name>`` or ``rgbd`` (computed from the frames in order).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from locnerf.data.posed_images import PosedImages
from locnerf.data.trajectory_files import read_trajectory, sample_trajectory
from locnerf.errors import DatasetError
from locnerf.geometry.se3 import pose_inverse
from locnerf.odometry.rgbd import RgbdOdometry, RgbdOdometryConfig, register_colour

logger = logging.getLogger(__name__)

DEFAULT_MAX_GAP_S = 0.2
"""Longest spacing of two file samples across which a stamp between them is interpolated, seconds."""


@dataclass(frozen=True)
class OdometryTrack:
    """Real odometry on the stamps of a run.

    Attributes:
        poses: (K, 4, 4) float64 ``T_odom_cam``, metres (identity where ``valid`` is False).
        valid: (K,) bool: whether the stamp has odometry (False: a gap).
        label: ``file:<name>`` or ``rgbd``.
        report: counts for the result JSON (poses, gaps and their reasons, time per frame).
        from_camera: computed from the frames the run's camera delivers (RGB-D odometry), so that a
            simulated kidnapping reaches it as it would reach a robot's own odometry; a recorded file
            follows the recorded camera and cannot see such a jump.
    """

    poses: torch.Tensor
    valid: torch.Tensor
    label: str
    report: dict[str, Any] = field(default_factory=dict)
    from_camera: bool = False

    def __post_init__(self) -> None:
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4) or self.valid.shape != (len(self.poses),):
            raise ValueError(f"odometry track of poses {tuple(self.poses.shape)} and valid {tuple(self.valid.shape)}: expected (K, 4, 4) and (K,)")


def file_track(
    path: str | Path, stamps: torch.Tensor, file_format: str = "auto", T_body_cam: torch.Tensor | None = None, max_gap: float = DEFAULT_MAX_GAP_S
) -> OdometryTrack:
    """A trajectory file (TUM or EuRoC, :mod:`locnerf.data.trajectory_files`) on ``stamps`` (K,) seconds,
    its body carried to the camera with ``T_body_cam`` (4, 4, metres, OpenGL camera axes; None: identity).

    Raises:
        FileNotFoundError / DatasetError: the file is unreadable, malformed (file and line named), or
            its stamps never overlap ``stamps``.
    """
    trajectory = read_trajectory(path, file_format)
    poses, valid = sample_trajectory(trajectory, stamps.double().numpy(), max_gap)
    if T_body_cam is not None:
        poses = poses @ T_body_cam.double()
    gaps = int((~valid).sum())
    logger.info("odometry %s: %d of %d stamps matched, %d gaps", path, int(valid.sum()), len(valid), gaps)
    report = {"file": str(path), "samples": len(trajectory), "poses": int(valid.sum()), "gaps": gaps}
    return OdometryTrack(poses, torch.from_numpy(valid), f"file:{Path(path).name}", report)


def rgbd_track(frames: PosedImages, frame_indices: list[int], stamps: torch.Tensor, config: RgbdOdometryConfig) -> OdometryTrack:
    """RGB-D odometry computed on ``frames`` (with depth, in metres: depth images, poses and ``T_cam_depth``, as
    :func:`locnerf.sim.paths.read_sequence_frames` gives them, whatever map units their normalization names) in the order ``frame_indices`` (K,),
    frame ``frame_indices[k]`` taken at ``stamps[k]``: the frames are fed one by one to
    :class:`~locnerf.odometry.rgbd.RgbdOdometry` as a camera would deliver them.

    The odometry measures the depth camera, with the colour registered onto its grid through the two
    cameras' placement (``frames.T_cam_depth``, when the colour camera was calibrated); poses are carried
    to the colour camera.

    Raises:
        DatasetError: the frames have no depth images.
    """
    if frames.depths is None or frames.depth_intrinsics is None:
        raise DatasetError(f"{frames.source}: RGB-D odometry needs depth images, and these frames have none")
    odometry = RgbdOdometry(config, frames.depth_intrinsics)
    T_depth_cam = torch.eye(4, dtype=torch.float64)
    T_cam_depth = None
    if frames.T_cam_depth is not None:
        T_depth_cam, T_cam_depth = pose_inverse(frames.T_cam_depth.double()), frames.T_cam_depth.double().numpy()
    poses = torch.eye(4, dtype=torch.float64).repeat(len(stamps), 1, 1)
    valid = torch.zeros(len(stamps), dtype=torch.bool)
    for k, (stamp, index) in enumerate(zip(stamps.tolist(), frame_indices)):
        rgb = np.ascontiguousarray((frames.images[index].numpy() * 255.0 + 0.5).astype(np.uint8))
        depth = frames.depths[index].numpy().astype(np.float32)
        pose = odometry.step(stamp, register_colour(rgb, frames.intrinsics, frames.depth_intrinsics, depth, T_cam_depth), depth)
        if pose is not None:
            poses[k], valid[k] = pose @ T_depth_cam, True
    report = {"kind": config.kind, **odometry.counters.as_dict()}
    logger.info("RGB-D odometry: %s", report)
    return OdometryTrack(poses, valid, "rgbd", report, from_camera=True)
