"""Render whole images by streaming pixel rays through a ray-colour callable in chunks."""

from __future__ import annotations

from typing import Callable

import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels

RenderRays = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


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
    pixels = pixel_grid(intrinsics, device=T_world_cam.device).to(T_world_cam.dtype)
    origins, directions = rays_from_poses_and_pixels(T_world_cam[None], pixels, intrinsics)
    origins, directions = origins[0], directions[0]
    with torch.no_grad():
        colours = [render_rays(origins[i : i + chunk], directions[i : i + chunk]) for i in range(0, len(origins), chunk)]
    return torch.cat(colours).reshape(intrinsics.height, intrinsics.width, 3)
