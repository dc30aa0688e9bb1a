"""A global start seeded by place recognition: the first image says where to put the particles.

A uniform global start (:meth:`locnerf.filter.localizer.Localizer.initialize_uniform`) spreads the
particles over the search region with a guessed tilt: level, the camera's y axis along the map's
``up`` (:func:`locnerf.filter.initialization.level_rotation`). Where the cameras
are tilted, as on an object-centred map (the lego orbit looks down at the object from 7° to 47° of
elevation, its ``up`` axis is z), no uniform particle sees what the camera sees and the filter
waits for kidnapping recovery to land near the truth by chance. With ``share`` > 0 the first
update's image is matched against the map's keyframes (:mod:`locnerf.filter.keyframes`) before it
is rendered and that share of the particles is re-drawn around the best matches, as recovery draws
its keyframe share (:func:`locnerf.filter.recovery.keyframe_draws`, with recovery's
``keyframe_count`` and spreads, orbit draws included); the others
stay uniform, in case the match is wrong.

In a room, the map's own views (the training frames) are few places: on the kitchen the test views lie
0.2-1 m and 10-70° from every one of them. With ``lattice`` set the keyframes are a lattice of views
rendered over the room instead (:mod:`locnerf.maps.view_lattice`: positions on a grid, headings every
few degrees, a few pitches), so the best matches are near the truth in position and heading. With
``keep_tilt`` (gravity known) a re-drawn particle takes its position and heading from the draw and its
roll and pitch from the particle it replaces: the lattice's pitches are only approximate.
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.filter.initialization import rotation_about_axis
from locnerf.filter.recovery import KeyframeCandidates, RecoveryConfig, keyframe_draws


class ViewLatticeConfig(BaseModel):
    """Keyframes rendered over the room: positions on a grid, headings about ``up`` and pitches (see
    :func:`locnerf.maps.view_lattice.lattice_poses`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    step: float = Field(0.2, gt=0, description="Grid spacing of the positions (map units), over the map's camera bounds widened by margin.")
    margin: float = Field(0.2, ge=0, description="How far (map units) the grid reaches beyond the map's camera bounds on every side.")
    yaw_step_deg: float = Field(30.0, gt=0, le=180, description="Spacing of the headings about the map's up axis (degrees).")
    pitches_deg: tuple[float, ...] = Field((-22.0, -32.0), min_length=1, description="Camera pitches (degrees, negative: looking down).")
    width: int = Field(16, ge=2, description="Thumbnail width (pixels).")
    supersample: int = Field(2, ge=1, description="Rays per thumbnail pixel along each axis.")


class KeyframeStartConfig(BaseModel):
    """Re-drawing part of a uniform global start around the keyframes that match the first image."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    share: float = Field(
        0.0, ge=0, le=1, description="Share of the particles of a uniform global start re-drawn around the keyframes that match the first image (0: off)."
    )
    keep_tilt: bool = Field(
        False, description="Re-drawn particles keep the roll and pitch of the particles they replace (gravity known); position and heading from the draw."
    )
    refine_updates: int = Field(
        0,
        ge=0,
        description="With recovery enabled: after the seeding, this many refining updates re-draw recovery.refine_fraction of the particles "
        "from the cloud's own Gaussian (recovery.refine_*), as after a relocalization (0: none).",
    )
    lattice: ViewLatticeConfig | None = Field(
        None, description="Keyframes rendered on a lattice over the room instead of the map's reference poses (for recovery too)."
    )


def seed_start(
    poses: torch.Tensor,
    candidates: KeyframeCandidates,
    start: KeyframeStartConfig,
    recovery: RecoveryConfig,
    generator: torch.Generator,
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> torch.Tensor:
    """:func:`seed_around_keyframes` by ``start``'s share; with ``start.keep_tilt`` the re-drawn poses
    take the tilt of those they replace (:func:`with_tilt_of`). Returns (N, 4, 4) like ``poses``."""
    seeded = seed_around_keyframes(poses, candidates, start.share, recovery, generator, up)
    if not start.keep_tilt:
        return seeded
    moved = (seeded != poses).flatten(1).any(dim=1)
    seeded[moved] = with_tilt_of(seeded[moved].double(), poses[moved].double(), up).to(poses.dtype)
    return seeded


def heading(rotations: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """Heading angles (N,) float64 of camera rotations (N, 3, 3) about the unit ``up`` (3,): the angle of
    the viewing direction's horizontal part (the camera's up axis where the camera looks along ``up``)."""
    horizontal = torch.eye(3, dtype=torch.float64)[int(torch.argmin(up.abs()))]
    first = horizontal - (horizontal @ up) * up
    first = first / torch.linalg.vector_norm(first)
    second = torch.linalg.cross(up, first)
    direction = -rotations[:, :, 2]
    flat = direction - (direction @ up)[:, None] * up
    vertical = torch.linalg.vector_norm(flat, dim=1) < 1e-6
    flat[vertical] = rotations[vertical][:, :, 1]
    return torch.atan2(flat @ second, flat @ first)


def with_tilt_of(drawn: torch.Tensor, tilted: torch.Tensor, up: tuple[float, float, float]) -> torch.Tensor:
    """Poses (N, 4, 4) float64 with the positions and headings of ``drawn`` (N, 4, 4) and the roll and
    pitch of ``tilted`` (N, 4, 4): each ``tilted`` rotation turned about ``up`` to ``drawn``'s heading."""
    axis = torch.tensor(up, dtype=torch.float64)
    axis = axis / torch.linalg.vector_norm(axis)
    turn = rotation_about_axis(axis, heading(drawn[:, :3, :3], axis) - heading(tilted[:, :3, :3], axis))
    result = drawn.clone()
    result[:, :3, :3] = turn @ tilted[:, :3, :3]
    return result


def seed_around_keyframes(
    poses: torch.Tensor,
    candidates: KeyframeCandidates,
    share: float,
    recovery: RecoveryConfig,
    generator: torch.Generator,
    up: tuple[float, float, float] = (0.0, 1.0, 0.0),
) -> torch.Tensor:
    """``poses`` (N, 4, 4) with ``round(share · N)`` of them, chosen at random, re-drawn around
    ``candidates`` (``up``, the world axis opposite to gravity, levels orbit draws).

    Returns:
        (N, 4, 4) poses of the dtype and device of ``poses`` (a new tensor).
    """
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"share={share}: expected a fraction in [0, 1]")
    count = round(share * poses.shape[0])
    seeded = poses.clone()
    if count == 0:
        return seeded
    fresh = keyframe_draws(candidates, count, recovery, up, generator)
    chosen = torch.randperm(poses.shape[0], generator=generator)[:count].to(poses.device)
    seeded[chosen] = fresh.to(poses.device, poses.dtype)
    return seeded
