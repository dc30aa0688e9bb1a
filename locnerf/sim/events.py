"""What a sensor stream yields: stamped odometry, images and ground truth, in time order.

The one set of sensor events of locnerf: the simulator (:mod:`locnerf.sim.stream`) and every
source of the ingest service (replays, EuRoC, a camera, ROS 2) produce them, and the ingest turns
them into wire messages. Poses are float64 and metric, in the data set's world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from locnerf.render.camera import PinholeIntrinsics


@dataclass(frozen=True)
class OdometryEvent:
    """VIO output at ``stamp``: ``T_odom_body`` (4, 4) float64, metres."""

    stamp: float
    T_odom_body: torch.Tensor


@dataclass(frozen=True)
class ImageEvent:
    """A camera frame at ``stamp``: ``pixels`` (H, W, 3) uint8 RGB."""

    stamp: float
    pixels: np.ndarray
    intrinsics: PinholeIntrinsics


@dataclass(frozen=True)
class GroundTruthEvent:
    """The true camera pose ``T_world_cam`` (4, 4) float64 at ``stamp`` (metres, map's world frame)."""

    stamp: float
    T_world_cam: torch.Tensor


SensorEvent = OdometryEvent | ImageEvent | GroundTruthEvent


def rgb8(image: torch.Tensor) -> np.ndarray:
    """An image (H, W, 3) of [0, 1] colours -> contiguous (H, W, 3) uint8, rounded to the nearest level."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {tuple(image.shape)}")
    return np.ascontiguousarray((image.float().cpu().clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy())
