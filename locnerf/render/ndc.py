"""Normalised device coordinates for forward-facing scenes (LLFF), as nerf-pytorch defines them.

A world-frame ray is first moved to start on the plane ``z = -near_plane`` of the map frame, then
projected so that NDC ``z`` runs from -1 (that plane) to +1 (infinity) as the ray parameter runs
from 0 to 1; x and y are the perspective image coordinates of a camera at the map origin looking
along -z with the given intrinsics.

Only rays that look towards -z (``d_z < 0``, :func:`rays_facing_scene`) have an NDC ray: a ray with
``d_z > 0`` would be moved backwards onto the plane and come out as the mirrored ray (from the
origin, ``(0.1, 0.05, 1)`` and ``(-0.1, -0.05, -1)`` give the same NDC ray), and ``d_z = 0`` gives
NaN. Such rays never see a forward-facing scene; :func:`ndc_rays_from_world_rays` refuses them and
the map renders them as its background (:meth:`locnerf.field.map_info.MapInfo.render_world_rays`).
"""

from __future__ import annotations

import torch

from locnerf.render.camera import PinholeIntrinsics


def rays_facing_scene(directions: torch.Tensor) -> torch.Tensor:
    """Which rays look towards -z, the only ones that can see a forward-facing scene.

    Args:
        directions: (..., 3) ray directions in the map frame.
    Returns:
        (...) bool, True where ``d_z < 0`` (False for NaN directions too).
    """
    return directions[..., 2] < 0


def ndc_rays_from_world_rays(
    origins: torch.Tensor, directions: torch.Tensor, intrinsics: PinholeIntrinsics, near_plane: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """Warp world-frame rays to NDC.

    Args:
        origins: (R, 3) ray origins in the map frame.
        directions: (R, 3) ray directions (any length; each must look towards -z, see :func:`rays_facing_scene`).
        intrinsics: the camera defining the NDC projection (width/fx and height/fy matter).
        near_plane: depth of the plane where NDC rays start (map units).
    Returns:
        ndc_origins: (R, 3) on NDC z = -1, ndc_directions: (R, 3) so that ``o + 1·d`` is at z = +1.
    Raises:
        ValueError: when a direction does not look towards -z (it has no NDC ray).
    """
    facing = rays_facing_scene(directions)
    if not bool(facing.all()):
        away = int((~facing).sum())
        raise ValueError(f"{away} of {facing.numel()} ray directions have d_z >= 0 (or NaN): expected rays looking towards -z, the only ones with an NDC ray")
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
