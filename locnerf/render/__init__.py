"""Cameras, rays for a batch of poses and pixels, samplers and volume rendering.

This package never imports :mod:`locnerf.field`: fields are passed in as callables.
"""

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import RenderRays, render_image
from locnerf.render.rays import camera_directions_from_pixels, pixel_grid, rays_from_poses_and_pixels

__all__ = ["PinholeIntrinsics", "RenderRays", "render_image", "camera_directions_from_pixels", "pixel_grid", "rays_from_poses_and_pixels"]
