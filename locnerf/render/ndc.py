"""Normalised device coordinates for forward-facing scenes (LLFF), as nerf-pytorch defines them.

A world-frame ray is first moved to start on the plane ``z = -near_plane`` of the map frame, then
projected so that NDC ``z`` runs from -1 (that plane) to +1 (infinity) as the ray parameter runs
from 0 to 1; x and y are the perspective image coordinates of a camera at the map origin looking
along -z with the given intrinsics.
"""

from __future__ import annotations

import torch

from locnerf.render.camera import PinholeIntrinsics


def ndc_rays_from_world_rays(
    origins: torch.Tensor, directions: torch.Tensor, intrinsics: PinholeIntrinsics, near_plane: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """Warp world-frame rays to NDC.

    Args:
        origins: (R, 3) ray origins in the map frame.
        directions: (R, 3) ray directions (any length; must look towards -z).
        intrinsics: the camera defining the NDC projection (width/fx and height/fy matter).
        near_plane: depth of the plane where NDC rays start (map units).
    Returns:
        ndc_origins: (R, 3) on NDC z = -1, ndc_directions: (R, 3) so that ``o + 1·d`` is at z = +1.
    """
    t_plane = -(near_plane + origins[..., 2]) / directions[..., 2]
    origins = origins + t_plane[..., None] * directions
    ax = -2.0 * intrinsics.fx / intrinsics.width
    ay = -2.0 * intrinsics.fy / intrinsics.height
    oz = origins[..., 2]
    ndc_origins = torch.stack((ax * origins[..., 0] / oz, ay * origins[..., 1] / oz, 1.0 + 2.0 * near_plane / oz), dim=-1)
    ndc_directions = torch.stack(
        (
            ax * (directions[..., 0] / directions[..., 2] - origins[..., 0] / oz),
            ay * (directions[..., 1] / directions[..., 2] - origins[..., 1] / oz),
            -2.0 * near_plane / oz,
        ),
        dim=-1,
    )
    return ndc_origins, ndc_directions
