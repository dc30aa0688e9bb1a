"""What a sensor stream yields: stamped odometry, images and ground truth, in time order.

The one set of sensor events of locnerf: the simulator (:mod:`locnerf.sim.stream`) and every
source of the ingest service (replays, EuRoC, a camera, ROS 2) produce them, and the ingest turns
them into wire messages. Poses are float64 and metric, in the data set's world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from locnerf.data.colour_camera import metric_offset
from locnerf.data.posed_images import PosedImages
from locnerf.render.camera import PinholeIntrinsics


@dataclass(frozen=True)
class OdometryEvent:
    """VIO output at ``stamp``: ``T_odom_body`` (4, 4) float64, metres. ``stamp_ns``: the same stamp in
    whole nanoseconds where the source has it exactly (a ROS 2 bag); None: derived from ``stamp``."""

    stamp: float
    T_odom_body: torch.Tensor
    stamp_ns: int | None = None


@dataclass(frozen=True)
class DepthFrame:
    """The depth image taken with a camera frame (RGB-D cameras): ``millimetres`` (Hd, Wd) uint16
    along the depth camera's optical axis, 0 = no reading, seen with ``intrinsics`` from the colour camera's pose
    times ``T_cam_depth`` ((4, 4) float64, metres: the depth camera's pose in the colour camera's frame; None: the same pose)."""

    millimetres: np.ndarray
    intrinsics: PinholeIntrinsics
    T_cam_depth: torch.Tensor | None = None


@dataclass(frozen=True)
class ImageEvent:
    """A camera frame at ``stamp``: ``pixels`` (H, W, 3) uint8 RGB, and its ``depth`` from an RGB-D camera (None: colour only);
    ``stamp_ns`` as :class:`OdometryEvent`'s."""

    stamp: float
    pixels: np.ndarray
    intrinsics: PinholeIntrinsics
    depth: DepthFrame | None = None
    stamp_ns: int | None = None


@dataclass(frozen=True)
class GroundTruthEvent:
    """The true camera pose ``T_world_cam`` (4, 4) float64 at ``stamp`` (metres, map's world frame); ``stamp_ns`` as :class:`OdometryEvent`'s."""

    stamp: float
    T_world_cam: torch.Tensor
    stamp_ns: int | None = None


@dataclass(frozen=True)
class RgbdFrameEvent:
    """An RGB-D camera frame for the ingest's online odometry (services/sensor_ingest/odometry_stage.py),
    not sent on the wire: the stage turns it into an :class:`OdometryEvent` of the colour camera.
    ``frame.pixels`` (H, W, 3) uint8 RGB, ``frame.depth`` its depth image (required)."""

    stamp: float
    frame: ImageEvent

    def __post_init__(self) -> None:
        if self.frame.depth is None:
            raise ValueError(f"RGB-D frame at {self.stamp} s without a depth image: the odometry needs one")


SensorEvent = OdometryEvent | ImageEvent | GroundTruthEvent | RgbdFrameEvent


def depth_millimetres(depth: torch.Tensor, scale: float = 1.0) -> np.ndarray:
    """A depth image (Hd, Wd) in map units (``scale`` map units per metre, 0 = no reading) -> contiguous
    (Hd, Wd) uint16 millimetres, rounded; readings beyond the 65.534 m that uint16 holds become 0 (no reading)."""
    if depth.ndim != 2:
        raise ValueError(f"depth image: expected shape (H, W), got {tuple(depth.shape)}")
    millimetres = torch.round(depth.double().cpu() / scale * 1000.0)
    millimetres = torch.where((millimetres > 0) & (millimetres < 65535), millimetres, torch.zeros_like(millimetres))
    return np.ascontiguousarray(millimetres.to(torch.int32).numpy().astype(np.uint16))


def posed_depth_frame(frames: PosedImages, index: int) -> DepthFrame | None:
    """The depth image of frame ``index`` of a posed sequence as sent (uint16 millimetres), or None without depth."""
    if frames.depths is None or frames.depth_intrinsics is None:
        return None
    return DepthFrame(depth_millimetres(frames.depths[index], frames.normalization.scale), frames.depth_intrinsics, metric_offset(frames))


def rgb8(image: torch.Tensor) -> np.ndarray:
    """An image (H, W, 3) of [0, 1] colours -> contiguous (H, W, 3) uint8, rounded to the nearest level."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {tuple(image.shape)}")
    return np.ascontiguousarray((image.float().cpu().clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy())
