"""Rays through chosen pixels, for a batch of camera poses at once.

Cameras use OpenGL axes (x right, y up, looking along -z). The direction of the ray through pixel
``(u, v)`` in the camera frame is ``((u - cx)/fx, -(v - cy)/fy, -1)``: not normalised, so that a
sample at parameter ``t`` lies at depth ``t`` along the optical axis, as NeRF's renderers expect.
"""

from __future__ import annotations

import torch

from locnerf.render.camera import PinholeIntrinsics


def camera_directions_from_pixels(pixels: torch.Tensor, intrinsics: PinholeIntrinsics) -> torch.Tensor:
    """Camera-frame ray directions (z = -1) for pixel coordinates.

    Args:
        pixels: (..., 2) as (u, v) = (column, row), float or integer.
    Returns:
        (..., 3) directions in the OpenGL camera frame.
    """
    pixels = pixels.to(torch.get_default_dtype()) if not pixels.is_floating_point() else pixels
    x = (pixels[..., 0] - intrinsics.cx) / intrinsics.fx
    y = -(pixels[..., 1] - intrinsics.cy) / intrinsics.fy
    return torch.stack((x, y, -torch.ones_like(x)), dim=-1)


def rays_from_poses_and_pixels(T_world_cam: torch.Tensor, pixels: torch.Tensor, intrinsics: PinholeIntrinsics) -> tuple[torch.Tensor, torch.Tensor]:
    """World-frame rays through the same pixels from every pose.

    Args:
        T_world_cam: (N, 4, 4) camera-to-world poses (OpenGL camera axes).
        pixels: (M, 2) pixel coordinates (u, v).
        intrinsics: the camera the pixels belong to.
    Returns:
        origins: (N, M, 3) and directions: (N, M, 3), in the poses' dtype and device.
    """
    dirs_cam = camera_directions_from_pixels(pixels.to(T_world_cam.device, T_world_cam.dtype), intrinsics)
    rotation = T_world_cam[:, :3, :3]  # (N, 3, 3)
    directions = torch.einsum("nij,mj->nmi", rotation, dirs_cam)
    origins = T_world_cam[:, None, :3, 3].expand_as(directions)
    return origins, directions


def pixel_grid(intrinsics: PinholeIntrinsics, device: torch.device | str = "cpu") -> torch.Tensor:
    """Integer pixel coordinates of a whole image, row-major: (H·W, 2) as (u, v), float."""
    v, u = torch.meshgrid(
        torch.arange(intrinsics.height, device=device, dtype=torch.get_default_dtype()),
        torch.arange(intrinsics.width, device=device, dtype=torch.get_default_dtype()),
        indexing="ij",
    )
    return torch.stack((u.reshape(-1), v.reshape(-1)), dim=-1)
