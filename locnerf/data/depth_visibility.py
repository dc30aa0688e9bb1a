"""Which frames of an RGB-D sequence see a world point: projection into a camera and a depth test.

A point is seen in a frame when it projects into that frame's depth image and the reading there is
the point's own depth (within a relative tolerance): not occluded, not off the image, not a hole.
The colour camera's calibration (:mod:`locnerf.data.colour_camera`) and the re-projection ceiling
(:mod:`locnerf.eval.reprojection_ceiling`) use it to find the training views that recorded a point.
"""

from __future__ import annotations

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.filter.warp import points_in_cameras, project_camera_points
from locnerf.render.camera import PinholeIntrinsics


def project_world_points(points: torch.Tensor, T_world_cam: torch.Tensor, camera: PinholeIntrinsics) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pixels (P, 2) (u, v), depth along the optical axis (P,) and (P,) bool inside ``camera``'s image and in front of it,
    of homogeneous world points (P, 4) seen from ``T_world_cam`` (4, 4) (OpenGL axes). Pixels keep their gradient."""
    local = points_in_cameras(T_world_cam[None], points)[0]
    pixels, in_front = project_camera_points(local, camera)
    u, v = pixels[:, 0].detach(), pixels[:, 1].detach()
    inside = in_front & (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= camera.height - 1)
    return pixels, -local[:, 2], inside


def seen_in_depth(images: PosedImages, frame: int, points: torch.Tensor, tolerance: float) -> torch.Tensor:
    """(P,) bool: the depth image of ``frame`` reads the points' own depth, within ``tolerance`` of it (a fraction).

    Args:
        images: frames with depth images (the depth camera at :meth:`PosedImages.depth_poses`).
        points: (P, 4) homogeneous world points, float64.
    Raises:
        ValueError: if ``images`` has no depth images.
    """
    if images.depths is None or images.depth_intrinsics is None:
        raise ValueError(f"{images.source}: a depth test needs depth images")
    camera = images.depth_intrinsics
    pixels, depth, inside = project_world_points(points, images.depth_poses()[frame], camera)
    column, row = pixels[:, 0].round().long().clamp(0, camera.width - 1), pixels[:, 1].round().long().clamp(0, camera.height - 1)
    reading = images.depths[frame].double()[row, column]
    return inside & (reading > 0) & ((reading - depth).abs() <= tolerance * depth)
