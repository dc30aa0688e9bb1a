"""Keyframes rendered on a lattice over a room: places to look for a lost camera by image retrieval.

A map's reference poses are where its training camera went; in a room another trajectory passes
far from them (kitchen: the test views lie 0.2-1 m and 10-70° from every training frame), so the
training frame most like an image says little about where it was taken. The lattice renders the map
instead at positions on a grid over the map's camera bounds (widened by a margin), at headings every
``yaw_step_deg`` about the map's up axis and at a few pitches, and keeps each view's thumbnail
(:mod:`locnerf.filter.keyframes`). The thumbnails are low-passed (area-averaged from ``supersample``²
rays per pixel), so a query matches views some decimetres and degrees away: a coarse likelihood over
the whole room, paid once per map instead of once per image.
"""

from __future__ import annotations

import logging
import math
import time

import torch

from locnerf.field.protocol import RadianceMap
from locnerf.filter.initialization import level_rotation, rotation_about_axis
from locnerf.filter.keyframe_start import ViewLatticeConfig
from locnerf.filter.keyframes import KeyframeIndex, thumbnail_camera, thumbnail_descriptors, thumbnail_shape
from locnerf.geometry.se3 import make_pose
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_views

logger = logging.getLogger(__name__)

_BATCH = 256
"""Views rendered per call (bounds memory: 256 × 32 × 24 rays at the defaults)."""


def lattice_poses(bounds: torch.Tensor, up: tuple[float, float, float], config: ViewLatticeConfig) -> torch.Tensor:
    """(P · Y · T, 4, 4) float64 camera-to-world poses: every grid position (P) of ``bounds`` (2, 3)
    widened by ``config.margin``, at every heading (Y) and pitch (T), position-major.

    A pose's rotation is the level camera (:func:`level_rotation` of ``up``) pitched about its x axis
    (negative: looking down), then turned about ``up`` by the heading."""
    bounds = bounds.double().cpu()
    if bounds.shape != (2, 3) or not bool((bounds[1] >= bounds[0]).all()):
        raise ValueError(f"lattice bounds {bounds.tolist()}: expected (2, 3) min and max corners")
    low, high = bounds[0] - config.margin, bounds[1] + config.margin
    axes = [low[i] + config.step * torch.arange(int(math.floor(float(high[i] - low[i]) / config.step + 1e-9)) + 1, dtype=torch.float64) for i in range(3)]
    positions = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    axis = torch.tensor(up, dtype=torch.float64)
    axis = axis / torch.linalg.vector_norm(axis)
    yaws = torch.deg2rad(torch.arange(0.0, 360.0 - 1e-9, config.yaw_step_deg, dtype=torch.float64))
    pitches = torch.deg2rad(torch.tensor(config.pitches_deg, dtype=torch.float64))
    pitched = level_rotation(up) @ rotation_about_axis(torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), pitches)  # (T, 3, 3)
    rotations = (rotation_about_axis(axis, yaws)[:, None] @ pitched[None]).reshape(-1, 3, 3)  # (Y·T, 3, 3)
    return make_pose(rotations.repeat(positions.shape[0], 1, 1), positions.repeat_interleave(rotations.shape[0], dim=0))


def build_lattice_index(radiance_map: RadianceMap, intrinsics: PinholeIntrinsics, config: ViewLatticeConfig) -> KeyframeIndex:
    """The map's thumbnails at every :func:`lattice_poses` pose (its camera bounds and up axis), for
    images of ``intrinsics``. The index's spacing is the grid's ``step``."""
    poses = lattice_poses(radiance_map.camera_bounds(), radiance_map.normalization.up, config)
    camera = thumbnail_camera(intrinsics, config.width, config.supersample)
    shape = thumbnail_shape(intrinsics, config.width)
    started = time.perf_counter()
    device_poses = poses.to(radiance_map.device, torch.float32)
    descriptors = torch.cat(
        [thumbnail_descriptors(render_views(radiance_map.render_rays, device_poses[i : i + _BATCH], camera).cpu(), shape) for i in range(0, len(poses), _BATCH)]
    )
    logger.info(
        "view lattice: %d views (%d×%d thumbnails from %d rays each), built in %.1f s",
        len(poses),
        shape[1],
        shape[0],
        camera.width * camera.height,
        time.perf_counter() - started,
    )
    return KeyframeIndex(poses, descriptors, shape, intrinsics, config.step)
