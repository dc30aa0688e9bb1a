"""A map as a coloured point cloud of occupied voxels, for viewers (``locnerf view``).

Every map kind is seen the same way: the map renders its surfaces (:func:`surface_renderer`) from a
few viewpoints (:func:`locnerf.maps.source.viewpoints`) at a small resolution; the surface points
that are opaque enough are binned into cubic voxels, and each occupied voxel becomes one point at its
centre with the mean colour of the surface points inside it. Points come out in the metric world
frame of the wire messages, so they sit under the poses the filter publishes.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization, RadianceMap, surface_renderer
from locnerf.geometry.se3 import pose_inverse
from locnerf.maps.source import viewpoints
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels

MIN_OPACITY = 0.5
"""Surface points of rays less opaque than this are left out (they met little or nothing)."""


@dataclass(frozen=True)
class MapCloud:
    """Occupied voxels of a map: ``points`` (P, 3) float32 voxel centres in metres (metric world frame),
    ``colours`` (P, 3) uint8 RGB, ``voxel`` the voxel edge in metres, ``up`` the unit vector opposite to
    gravity in the metric world frame."""

    points: torch.Tensor
    colours: torch.Tensor
    voxel: float
    up: tuple[float, float, float]


def points_to_metric(points: torch.Tensor, normalization: MapNormalization) -> torch.Tensor:
    """Map-frame points (P, 3) -> metric world-frame points (P, 3): ``T_dataset_map · p / scale`` (the inverse of
    :meth:`MapNormalization.metric_to_map` for points)."""
    T_dataset_map = pose_inverse(torch.tensor(normalization.T_map_dataset, dtype=points.dtype, device=points.device))
    return (points @ T_dataset_map[:3, :3].T + T_dataset_map[:3, 3]) / normalization.scale


def voxel_cloud(points: torch.Tensor, colours: torch.Tensor, voxel: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Points (P, 3) with colours (P, 3) in [0, 1] -> (centres (V, 3), mean colours (V, 3) in [0, 1]) of the
    ``voxel``-sized cubes (aligned to the origin) that hold at least one point, in the order of their indices."""
    if voxel <= 0:
        raise ValueError(f"voxel={voxel}: expected a positive edge length")
    index = torch.floor(points / voxel).long()
    cells, inverse = torch.unique(index, dim=0, return_inverse=True)
    counts = torch.zeros(len(cells), dtype=colours.dtype).index_add_(0, inverse, torch.ones_like(inverse, dtype=colours.dtype))
    sums = torch.zeros(len(cells), 3, dtype=colours.dtype).index_add_(0, inverse, colours)
    return (cells.to(points.dtype) + 0.5) * voxel, sums / counts[:, None]


def below_cameras(points: torch.Tensor, radiance_map: RadianceMap) -> torch.Tensor:
    """(P,) bool: map-frame points (P, 3) no higher, along the map's up axis, than the highest plausible camera
    position (:meth:`RadianceMap.camera_bounds`). A room then shows without its ceiling, and an object
    seen from above keeps all of it."""
    up = torch.tensor(radiance_map.normalization.up, dtype=points.dtype)
    bounds = radiance_map.camera_bounds().to(points.dtype).cpu()
    corners = torch.stack(torch.meshgrid(*(bounds[:, axis] for axis in range(3)), indexing="ij"), dim=-1).reshape(-1, 3)
    return points @ up <= float((corners @ up).max())


def map_cloud(radiance_map: RadianceMap, views: int = 24, width: int = 64, voxels_across: int = 120, seed: int = 0, cut_above_cameras: bool = True) -> MapCloud:
    """The occupied voxels of ``radiance_map`` seen from ``views`` viewpoints rendered ``width`` pixels wide.

    The voxel edge is the largest extent of the surface points over ``voxels_across``. With
    ``cut_above_cameras``, surfaces above every plausible camera position are left out (:func:`below_cameras`).

    Raises:
        LocnerfInputError: a map that cannot place its surfaces in space (NDC maps, nerf-pytorch maps).
    """
    render_surface = surface_renderer(radiance_map)
    if render_surface is None:
        raise LocnerfInputError(
            f"{type(radiance_map).__name__} (ndc={radiance_map.normalization.ndc}): expected a metric map that renders surfaces (a grid map or the world)"
        )
    intrinsics = radiance_map.default_intrinsics.scaled(width / radiance_map.default_intrinsics.width)
    poses = torch.stack(viewpoints(radiance_map, views, torch.Generator().manual_seed(seed))).float()
    pixels = pixel_grid(intrinsics).float()
    found_points, found_colours = [], []
    with torch.no_grad():
        for pose in poses.to(radiance_map.device):
            origins, directions = rays_from_poses_and_pixels(pose[None], pixels.to(pose.device), intrinsics)
            colours, points, opacity = render_surface(origins[0], directions[0])
            keep = opacity >= MIN_OPACITY
            found_points.append(points[keep].double().cpu())
            found_colours.append(colours[keep].double().cpu())
    points, colours = torch.cat(found_points), torch.cat(found_colours).clamp(0, 1)
    if cut_above_cameras:
        keep = below_cameras(points, radiance_map)
        points, colours = points[keep], colours[keep]
    if len(points) == 0:
        raise LocnerfInputError(f"{type(radiance_map).__name__}: no surface seen from {views} viewpoints (below the cameras: {cut_above_cameras})")
    voxel = max(float((points.amax(0) - points.amin(0)).max()) / radiance_map.normalization.scale, 1e-6) / voxels_across
    centres, colours = voxel_cloud(points_to_metric(points, radiance_map.normalization), colours, voxel)
    normalization = radiance_map.normalization
    R_dataset_map = torch.tensor(normalization.T_map_dataset, dtype=torch.float64)[:3, :3].T
    up = R_dataset_map @ torch.tensor(normalization.up, dtype=torch.float64)
    return MapCloud(centres.float(), (colours * 255).round().to(torch.uint8), voxel, tuple((up / up.norm()).tolist()))
