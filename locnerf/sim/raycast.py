"""Exact ray casting against axis-aligned boxes, vectorised over rays × boxes (slab test)."""

from __future__ import annotations

import torch

_PARALLEL = 1e-12


def ray_box_intervals(origins: torch.Tensor, directions: torch.Tensor, box_min: torch.Tensor, box_max: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Entry and exit parameters of rays through boxes, and the axes of the entry and exit faces.

    Args:
        origins, directions: (R, 3).
        box_min, box_max: (B, 3) corners.
    Returns:
        t_enter, t_exit: (R, B); a ray misses a box when ``t_enter > t_exit``.
        enter_axis, exit_axis: (R, B) int64 axis (0, 1, 2) of the face hit on entry / exit.
    """
    safe = torch.where(directions.abs() < _PARALLEL, torch.full_like(directions, _PARALLEL), directions)
    inverse = 1.0 / safe  # (R, 3)
    t0 = (box_min[None] - origins[:, None]) * inverse[:, None]  # (R, B, 3)
    t1 = (box_max[None] - origins[:, None]) * inverse[:, None]
    near, far = torch.minimum(t0, t1), torch.maximum(t0, t1)
    t_enter, enter_axis = near.max(dim=-1)
    t_exit, exit_axis = far.min(dim=-1)
    return t_enter, t_exit, enter_axis, exit_axis


def nearest_box_hit(origins: torch.Tensor, directions: torch.Tensor, box_min: torch.Tensor, box_max: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Nearest outside-facing hit of rays with solid boxes (rays starting inside a box ignore it).

    Returns:
        t: (R,) hit parameter (inf where nothing is hit); box: (R,) int64 index of the box hit;
        axis: (R,) int64 axis of the face hit.
    """
    if box_min.shape[0] == 0:
        no_hit = torch.full((origins.shape[0],), float("inf"), dtype=origins.dtype, device=origins.device)
        zeros = torch.zeros(origins.shape[0], dtype=torch.int64, device=origins.device)
        return no_hit, zeros, zeros
    t_enter, t_exit, enter_axis, _ = ray_box_intervals(origins, directions, box_min, box_max)
    valid = (t_enter <= t_exit) & (t_enter > 0)
    t = torch.where(valid, t_enter, torch.full_like(t_enter, float("inf")))
    t_best, box = t.min(dim=-1)
    axis = enter_axis.gather(1, box[:, None]).squeeze(1)
    return t_best, box, axis


def room_exit_hit(origins: torch.Tensor, directions: torch.Tensor, room_min: torch.Tensor, room_max: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where rays leave the inside of a room box: (t (R,), axis (R,), side (R,) 0 for min, 1 for max).

    ``t`` is inf for rays that never meet the room from the inside.
    """
    t_enter, t_exit, _, exit_axis = ray_box_intervals(origins, directions, room_min[None], room_max[None])
    t_enter, t_exit, exit_axis = t_enter[:, 0], t_exit[:, 0], exit_axis[:, 0]
    valid = (t_enter <= t_exit) & (t_exit > 0)
    t = torch.where(valid, t_exit, torch.full_like(t_exit, float("inf")))
    side = (directions.gather(1, exit_axis[:, None]).squeeze(1) > 0).to(torch.int64)
    return t, exit_axis, side
