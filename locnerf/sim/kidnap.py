"""Choosing a kidnapping's jump by its size: where along the path the camera lands.

A kidnapping (:mod:`locnerf.sim.scenario`) moves the true camera ``shift`` seconds ahead along
its path, unseen by the odometry. By default the shift is half a loop, whatever distance that
makes; here it is chosen so that the jump has a requested size: the pose at the kidnapping's
stamp ``t_k`` and the pose it lands on, ``t_k + shift``, are at least ``distance`` metres apart and
at least ``angle`` degrees turned, and among the shifts that qualify the one whose jump is nearest
to the request, ``(d / distance − 1)² + (θ / angle − 1)²``, is taken. Candidate shifts are every
frame of a recorded sequence (its images stay on frames), or every odometry period of a
continuous path, over one loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from locnerf.errors import LocnerfInputError
from locnerf.geometry import rotation_error_deg
from locnerf.sim.paths import CameraPath, SequencePath


@dataclass(frozen=True)
class KidnapJump:
    """A kidnapping's shift along the path and the jump it makes.

    Attributes:
        shift: seconds along the path (``ScenarioConfig.kidnap_shift``).
        distance: metres between the camera before and after the jump.
        angle_deg: degrees between the two camera orientations.
    """

    shift: float
    distance: float
    angle_deg: float


def kidnap_tick_stamp(kidnap_at: float, odom_rate: float) -> float:
    """The odometry stamp (seconds) of the first pose after a kidnapping at ``kidnap_at`` (as the scenario places it)."""
    return max(1, math.ceil(kidnap_at * odom_rate - 1e-9)) / odom_rate


def jump_of_shifts(path: CameraPath, stamp: float, shifts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances (S,) metres and angles (S,) degrees between the path's pose at ``stamp`` and at ``stamp + shifts`` (S,)."""
    before = path.poses_at(torch.tensor([stamp], dtype=torch.float64))
    after = path.poses_at(stamp + shifts.double())
    distances = (after[:, :3, 3] - before[:, :3, 3]).norm(dim=-1)
    return distances, rotation_error_deg(after, before.expand_as(after)).double()


def kidnap_shift_for_jump(path: CameraPath, kidnap_at: float, odom_rate: float, distance: float, angle_deg: float) -> KidnapJump:
    """The shift whose jump is at least ``distance`` metres and ``angle_deg`` degrees, nearest to them (module docstring).

    Raises:
        LocnerfInputError: a non-positive request, or no point of the loop that far from the kidnapping's pose
            (the message names the largest jump there is).
    """
    if not (distance > 0 and angle_deg > 0 and math.isfinite(distance) and math.isfinite(angle_deg)):
        raise LocnerfInputError(f"kidnap jump {distance} m, {angle_deg} deg: expected a positive distance and angle")
    step = path.frame_period if isinstance(path, SequencePath) else 1.0 / odom_rate
    count = max(1, round(path.duration / step))
    shifts = torch.arange(1, count, dtype=torch.float64) * step
    stamp = kidnap_tick_stamp(kidnap_at, odom_rate)
    distances, angles = jump_of_shifts(path, stamp, shifts)
    qualifies = (distances >= distance) & (angles >= angle_deg)
    if not bool(qualifies.any()):
        far = int(distances.argmax())
        raise LocnerfInputError(
            f"kidnap jump of at least {distance} m and {angle_deg} deg at {kidnap_at} s: no pose of the path is that far from the camera's there "
            f"(the farthest is {float(distances[far]):.3f} m and {float(angles[far]):.1f} deg away); expected a smaller jump"
        )
    cost = (distances / distance - 1) ** 2 + (angles / angle_deg - 1) ** 2
    best = int(torch.where(qualifies, cost, torch.full_like(cost, math.inf)).argmin())
    return KidnapJump(float(shifts[best]), float(distances[best]), float(angles[best]))
