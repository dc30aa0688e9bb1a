"""What a source yields: a time-ordered stream of stamped sensor events."""

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
