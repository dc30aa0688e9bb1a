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
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.filter.recovery import KeyframeCandidates, RecoveryConfig, keyframe_draws


class KeyframeStartConfig(BaseModel):
    """Re-drawing part of a uniform global start around the keyframes that match the first image."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    share: float = Field(
        0.0, ge=0, le=1, description="Share of the particles of a uniform global start re-drawn around the keyframes that match the first image (0: off)."
    )


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
