"""The depth term of an update on an RGB-D frame: what the filter sends its workers, and how a worker reads it.

An RGB-D frame's depth travels after its colour pixels (:func:`locnerf.messages.codec.decode_rgbd`)
as uint16 millimetres. When the localizer's ``measurement.depth`` is set, every update on such a
frame carries the depth image and the depth pixels drawn for it (the same for every shard, so the
shards' likelihoods compare); the workers add the depth term to the colour term
(:mod:`locnerf.filter.depth_measurement`).
"""

from __future__ import annotations

import numpy as np
import torch

from locnerf.filter.depth_measurement import DepthObservation, sample_depth_pixels
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.messages.schemas import DepthHeader, DepthRequest, Matrix
from locnerf.render.camera import PinholeIntrinsics

MILLIMETRES_PER_METRE = 1000.0


def depth_observation(
    depth_mm: np.ndarray, intrinsics: PinholeIntrinsics, scale: float, device: torch.device | str = "cpu", T_cam_depth: Matrix | None = None
) -> DepthObservation:
    """A wire depth image (Hd, Wd) uint16 millimetres, and the depth camera's offset from the colour camera
    (4×4, metres; None: none) -> the observation in map units (``scale`` map units per metre) on ``device``."""
    metres = torch.from_numpy(depth_mm.astype(np.float32)).to(device) / MILLIMETRES_PER_METRE
    offset = None if T_cam_depth is None else torch.tensor(T_cam_depth, dtype=torch.float64, device=device)
    return DepthObservation(metres, intrinsics, offset).scaled(scale)


def depth_request(depth_mm: np.ndarray, header: DepthHeader, measurement: MeasurementConfig, scale: float, generator: torch.Generator) -> DepthRequest:
    """The depth part of an update request: the image, its camera, and ``measurement.depth.pixels`` pixels
    drawn among its valid readings with ``generator``.

    Raises:
        ValueError: ``measurement.depth`` is unset, or the image has no valid reading.
    """
    if measurement.depth is None:
        raise ValueError("depth_request: measurement.depth is None; expected the depth settings")
    observation = depth_observation(depth_mm, header.intrinsics, scale)
    pixels = sample_depth_pixels(observation, measurement.depth, generator)
    image = np.ascontiguousarray(depth_mm, dtype="<u2").tobytes()
    return DepthRequest(image=image, intrinsics=header.intrinsics, T_cam_depth=header.T_cam_depth, measurement=measurement, pixels=pixels.tolist())
