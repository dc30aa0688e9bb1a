"""Pairing published poses with ground truth, for ``locnerf echo`` and ``locnerf up``."""

from __future__ import annotations

import collections
from dataclasses import dataclass

import torch

from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.messages.schemas import PoseEstimate, PoseStamped


@dataclass(frozen=True)
class PoseError:
    """Error of one estimate against the ground truth of the same stamp."""

    stamp: float
    translation: float
    rotation_deg: float


class GroundTruthMatcher:
    """Keeps recent ground truth by stamp and scores estimates of the same stamp.

    Args:
        capacity: ground-truth poses kept.
    """

    def __init__(self, capacity: int = 2000) -> None:
        self._truth: collections.OrderedDict[float, torch.Tensor] = collections.OrderedDict()
        self.capacity = capacity

    def add_truth(self, message: PoseStamped) -> None:
        """Remember a true pose."""
        self._truth[message.stamp] = torch.tensor(message.T_world_cam, dtype=torch.float64)
        while len(self._truth) > self.capacity:
            self._truth.popitem(last=False)

    def error(self, estimate: PoseEstimate) -> PoseError | None:
        """The estimate's error, or None if no ground truth has its stamp."""
        truth = self._truth.get(estimate.stamp)
        if truth is None:
            return None
        pose = torch.tensor(estimate.T_world_cam, dtype=torch.float64)
        return PoseError(estimate.stamp, float(translation_error(pose, truth)), float(rotation_error_deg(pose, truth)))


def pose_line(estimate: PoseEstimate, error: PoseError | None) -> str:
    """One printable line: stamp, position, mode, particles, and the error when known."""
    x, y, z = (row[3] for row in estimate.T_world_cam[:3])
    line = f"{estimate.stamp:9.3f}  xyz=({x:+.3f}, {y:+.3f}, {z:+.3f}) m  {estimate.mode:<12} n={estimate.particle_count:<4} spread={estimate.spread:.3f} m"
    if error is not None:
        line += f"  error={error.translation:.3f} m {error.rotation_deg:.2f}°"
    return line
