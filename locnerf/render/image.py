"""Render whole images by streaming pixel rays through a ray-colour callable in chunks."""

from __future__ import annotations

from collections.abc import Callable

import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels

RenderRays = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""A ray-colour callable: origins (R, 3), directions (R, 3) -> rgb (R, 3) in [0, 1] (a field and its renderer)."""

SurfaceRays = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]
"""Rays' colours and where they meet the scene: origins (R, 3), directions (R, 3), map frame ->
rgb (R, 3), expected surface point (R, 3) and opacity (R,) in [0, 1]."""

SurfaceDistanceLookup = Callable[[torch.Tensor], torch.Tensor]
"""Distances (...) from map-frame points (..., 3) to the nearest surface a map's depth readings measured
(:class:`locnerf.field.surface_distance.SurfaceDistance`)."""


def render_image(
    render_rays: RenderRays,
    T_world_cam: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    chunk: int = 65536,
) -> torch.Tensor:
    """Render every pixel seen from one pose.

    Args:
        render_rays: maps origins (R, 3), directions (R, 3) to rgb (R, 3).
        T_world_cam: (4, 4) camera-to-world pose (OpenGL axes).
        intrinsics: output camera.
        chunk: rays per call.
    Returns:
        (H, W, 3) image in [0, 1].
    """
    return render_views(render_rays, T_world_cam[None], intrinsics, chunk)[0]


def render_views(render_rays: RenderRays, poses: torch.Tensor, intrinsics: PinholeIntrinsics, chunk: int = 65536) -> torch.Tensor:
    """Every pixel seen from each of ``poses`` (N, 4, 4) -> (N, H, W, 3) images in [0, 1] (on the poses' device)."""
    pixels = pixel_grid(intrinsics, device=poses.device).to(poses.dtype)
    origins, directions = rays_from_poses_and_pixels(poses, pixels, intrinsics)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    with torch.no_grad():
        colours = [render_rays(origins[i : i + chunk], directions[i : i + chunk]) for i in range(0, len(origins), chunk)]
    return torch.cat(colours).reshape(poses.shape[0], intrinsics.height, intrinsics.width, 3)
