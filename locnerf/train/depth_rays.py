"""Depth supervision from RGB-D images: the depth camera's rays with a valid reading, and the loss on them.

Each valid depth pixel is a ray of the depth camera (its own intrinsics, posed at
``PosedImages.depth_poses()``; depth images are never resampled onto the colour images). Ray directions have camera z = -1
(:mod:`locnerf.render.rays`), so the observed ray parameter of a pixel is its depth reading.
"""

from __future__ import annotations

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels


def depth_training_rays(images: PosedImages, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays of every valid depth pixel: origins (N, 3), directions (N, 3), observed depth (N,), float32 map units.

    Raises:
        DatasetError: if the images carry no depth, or no valid depth pixel.
    """
    if images.depths is None or images.depth_intrinsics is None:
        raise DatasetError(f"{images.source}: no depth images to supervise with")
    pixels = pixel_grid(images.depth_intrinsics)
    origins, directions, depths = [], [], []
    for pose, depth in zip(images.depth_poses().float(), images.depths.float()):
        flat = depth.reshape(-1)
        valid = flat > 0
        ray_origins, ray_directions = rays_from_poses_and_pixels(pose[None], pixels[valid], images.depth_intrinsics)
        origins.append(ray_origins[0])
        directions.append(ray_directions[0])
        depths.append(flat[valid])
    if not sum(len(d) for d in depths):
        raise DatasetError(f"{images.source}: every depth pixel is invalid (0)")
    return torch.cat(origins).to(device), torch.cat(directions).to(device), torch.cat(depths).to(device)


def depth_loss(predicted: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Mean squared depth error (map units²) of rays: predicted (R,), observed (R,)."""
    return torch.mean((predicted - observed) ** 2)
