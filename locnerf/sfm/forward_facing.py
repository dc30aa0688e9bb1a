"""A forward-facing capture posed by structure from motion, in the NDC map frame LLFF's own tools give it.

LLFF's ``imgs2poses`` (Mildenhall et al. 2019) writes ``poses_bounds.npy`` from a COLMAP model: each image's
near and far bounds are the 0.1th and 99.9th percentiles of the depths of the 3D points it observes.
nerf-pytorch then scales and recentres the poses (:func:`locnerf.data.llff.normalize_forward_facing`) and
warps rays to normalised device coordinates. LLFF's percentiles trim outliers among the thousands of points a
full-resolution COLMAP run gives each image; a capture posed at low resolution gives a few hundred, where the
0.1th percentile is the nearest point, and a point triangulated from two views only can sit far in front of
the scene (fern at ÷8: 0.63 of the true near depth), which would scale the whole map frame by its error. Only
points tracked in at least ``MIN_TRACK_LENGTH`` images bound an image. :func:`forward_facing_frame` does the same from the
reconstruction, so an LLFF folder built with ``--sfm`` gets the map its ``poses_bounds.npy`` would give,
without reading that file; the map's "data-set world" is then the SfM map frame (metric when a scale source
was given).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from locnerf.data.llff import NDC_CUBE, forward_facing_normalization, normalize_forward_facing
from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError

logger = logging.getLogger(__name__)

BOUND_PERCENTILES = (0.1, 99.9)
"""LLFF ``imgs2poses``' percentiles of an image's point depths: its near and far bounds."""
MIN_TRACK_LENGTH = 3
"""Fewest images a 3D point is seen in for it to bound an image's depths (two-view points are the loosely triangulated ones)."""
MIN_POINTS = 10
"""Fewest such 3D points that give an image its bounds."""


def image_depth_bounds(reconstruction, names: list[str], scale: float = 1.0) -> np.ndarray:
    """(K, 2) float64 near and far bounds of the images ``names`` (in that order): percentiles of the depths of the 3D points each
    observes that are tracked in at least ``MIN_TRACK_LENGTH`` images.

    Args:
        reconstruction: pycolmap.Reconstruction holding the posed images ``names``.
        scale: units of the result per SfM unit (the map frame's scale).
    Raises:
        DatasetError: naming the images that observe fewer than ``MIN_POINTS`` points in front of them.
    """
    by_name = {image.name: image for image in reconstruction.images.values() if image.has_pose}
    bounds, sparse = [], []
    for name in names:
        image = by_name[name]
        points = [reconstruction.points3D[p.point3D_id] for p in image.points2D if p.has_point3D()]
        world = np.array([point.xyz for point in points if point.track.length() >= MIN_TRACK_LENGTH]).reshape(-1, 3)
        pose = image.cam_from_world().matrix()
        depths = world @ pose[:, :3].T[:, 2] + pose[2, 3]
        depths = depths[depths > 0]
        if len(depths) < MIN_POINTS:
            sparse.append(f"{name} ({len(depths)})")
            continue
        bounds.append(np.percentile(depths, BOUND_PERCENTILES))
    if sparse:
        raise DatasetError(
            f"forward-facing capture: images observing fewer than {MIN_POINTS} 3D points seen in >= {MIN_TRACK_LENGTH} images cannot be bounded: "
            f"{', '.join(sparse)}"
        )
    return np.asarray(bounds, dtype=np.float64) * scale


def forward_facing_frame(images: PosedImages, bounds: np.ndarray) -> tuple[PosedImages, dict[str, Any]]:
    """``images`` (posed in the SfM map frame) in the NDC map frame of nerf-pytorch's forward-facing normalisation, and its record.

    Args:
        images: posed images, OpenGL camera-to-world in the SfM map frame, no NDC.
        bounds: (K, 2) each image's near and far bounds in the same frame's units (:func:`image_depth_bounds`).
    Returns:
        the images with NDC normalisation (data-set world: the SfM map frame), and the metadata entry recording it.
    """
    T_world_cam, map_bounds, T_map_scaled, scale = normalize_forward_facing(images.T_world_cam[:, :3, :4].double().numpy(), bounds)
    normalization = forward_facing_normalization(T_map_scaled, scale, map_bounds)
    logger.info(
        "forward-facing: near bounds %.3f-%.3f, far %.3f-%.3f (SfM map units); NDC map units per SfM map unit %.4f",
        bounds[:, 0].min(),
        bounds[:, 0].max(),
        bounds[:, 1].min(),
        bounds[:, 1].max(),
        scale,
    )
    posed = replace(
        images.without_depth(),
        T_world_cam=torch.from_numpy(T_world_cam),
        near=normalization.near,
        far=normalization.far,
        normalization=normalization,
        scene_bounds=NDC_CUBE.clone(),
    )
    record = {
        "bounds": "depth percentiles of the SfM points each image observes (LLFF imgs2poses)",
        "percentiles": list(BOUND_PERCENTILES),
        "min_track_length": MIN_TRACK_LENGTH,
        "near_min": float(bounds[:, 0].min()),
        "far_max": float(bounds[:, 1].max()),
    }
    return posed, record
