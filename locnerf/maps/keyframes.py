"""The keyframe index of a map: thumbnails rendered at its reference poses (or at random poses of
the procedural world, or on a lattice over the room: :mod:`locnerf.maps.view_lattice`), for the
filter's keyframe start and recovery draws around keyframes."""

from __future__ import annotations

import logging
import time

import torch

from locnerf.field.protocol import RadianceMap
from locnerf.filter.keyframes import KeyframeIndex, index_from_views, thumbnail_camera
from locnerf.filter.localizer_config import LocalizerConfig
from locnerf.geometry.validation import validate_poses
from locnerf.maps.view_lattice import build_lattice_index
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import RenderRays, render_views
from locnerf.sim.world import ProceduralWorld

logger = logging.getLogger(__name__)


def keyframe_poses(radiance_map: RadianceMap, generator: torch.Generator, world_count: int = 200) -> torch.Tensor:
    """(K, 4, 4) float64 poses for a keyframe index: a map file's reference poses (every one), or
    ``world_count`` random plausible poses of the procedural world."""
    if isinstance(radiance_map, ProceduralWorld):
        return torch.stack([radiance_map.sample_camera_pose(generator) for _ in range(world_count)])
    return radiance_map.reference_poses().double()


def build_keyframe_index(render_rays: RenderRays, poses: torch.Tensor, intrinsics: PinholeIntrinsics, width: int = 16, supersample: int = 4) -> KeyframeIndex:
    """Render the map's thumbnail at every keyframe pose (K, 4, 4) (map frame, on the renderer's
    device) for images of ``intrinsics``: ``width`` pixels wide, from ``supersample``² rays each."""
    validate_poses(poses, name="keyframe poses")
    if poses.ndim != 3 or poses.shape[0] == 0:
        raise ValueError(f"keyframe poses: expected shape (K>=1, 4, 4), got {tuple(poses.shape)}")
    views = render_views(render_rays, poses.float(), thumbnail_camera(intrinsics, width, supersample))
    return index_from_views(poses, views, intrinsics, width)


def recovery_keyframes(config: LocalizerConfig, radiance_map: RadianceMap, intrinsics: PinholeIntrinsics, seed: int) -> KeyframeIndex | None:
    """The map's keyframe index for images of ``intrinsics``, when ``config``'s recovery or keyframe
    start draws around keyframes (:meth:`LocalizerConfig.uses_keyframes`); None otherwise. With
    ``keyframe_start.lattice`` set, the views of the lattice (:func:`build_lattice_index`), followed by the
    reference views when ``recovery.reference_views`` is set (:func:`joined_index`)."""
    if not config.uses_keyframes():
        return None
    lattice = build_lattice_index(radiance_map, intrinsics, config.keyframe_start.lattice) if config.keyframe_start.lattice is not None else None
    if lattice is not None and not config.recovery.reference_views:
        return lattice
    poses = keyframe_poses(radiance_map, torch.Generator().manual_seed(seed))
    started = time.perf_counter()
    index = build_keyframe_index(radiance_map.render_rays, poses.to(radiance_map.device), intrinsics)
    logger.info("keyframe index: %d keyframes, spacing %.3f map units, built in %.2f s", len(index), index.spacing, time.perf_counter() - started)
    return index if lattice is None else joined_index(lattice, index)


def joined_index(first: KeyframeIndex, second: KeyframeIndex) -> KeyframeIndex:
    """The views of ``first`` then ``second`` in one index, with ``first``'s spacing (``recovery.reference_views``:
    a view lattice and the map's reference views).

    Raises:
        ValueError: the two differ in thumbnail shape or camera.
    """
    if first.shape != second.shape or first.camera != second.camera:
        raise ValueError(
            f"joining keyframe indexes of thumbnails {first.shape} and {second.shape}, cameras {first.camera} and {second.camera}: expected the same"
        )
    poses = torch.cat([first.poses, second.poses])
    return KeyframeIndex(poses, torch.cat([first.descriptors, second.descriptors]), first.shape, first.camera, first.spacing)
