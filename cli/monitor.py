"""Pairing published poses with ground truth, for ``locnerf echo`` and ``locnerf up``."""

from __future__ import annotations

import collections
from dataclasses import dataclass

from locnerf.messages.schemas import Matrix, PoseEstimate, PoseStamped


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
        self._truth: collections.OrderedDict[float, Matrix] = collections.OrderedDict()
        self.capacity = capacity
        self.newest_stamp: float | None = None
        """Stamp of the newest true pose received (None: no ground truth yet)."""

    def add_truth(self, message: PoseStamped) -> None:
        """Remember a true pose."""
        self._truth[message.stamp] = message.T_world_cam
        self.newest_stamp = message.stamp if self.newest_stamp is None else max(self.newest_stamp, message.stamp)
        while len(self._truth) > self.capacity:
            self._truth.popitem(last=False)

    def settled(self, estimate: PoseEstimate) -> bool:
        """Whether the estimate's truth is known or will not come: it arrived, no ground truth is published
        (none seen yet), or truth of a later stamp arrived (one source publishes it in stamp order)."""
        return estimate.stamp in self._truth or self.newest_stamp is None or self.newest_stamp > estimate.stamp

    def error(self, estimate: PoseEstimate) -> PoseError | None:
        """The estimate's error, or None if no ground truth has its stamp.

        torch is imported at the first error, not with the module: ``locnerf echo`` without ground truth never needs it."""
        truth = self._truth.get(estimate.stamp)
        if truth is None:
            return None
        import torch

        from locnerf.geometry.metrics import rotation_error_deg, translation_error

        pose, true_pose = (torch.tensor(matrix, dtype=torch.float64) for matrix in (estimate.T_world_cam, truth))
        return PoseError(estimate.stamp, float(translation_error(pose, true_pose)), float(rotation_error_deg(pose, true_pose)))


def pose_line(estimate: PoseEstimate, error: PoseError | None) -> str:
    """One printable line: stamp, position, mode, particles, and the error when known."""
    x, y, z = (row[3] for row in estimate.T_world_cam[:3])
    line = f"{estimate.stamp:9.3f}  xyz=({x:+.3f}, {y:+.3f}, {z:+.3f}) m  {estimate.mode:<12} n={estimate.particle_count:<4} spread={estimate.spread:.3f} m"
    if error is not None:
        line += f"  error={error.translation:.3f} m {error.rotation_deg:.2f}°"
    return line


class ScoredPoses:
    """Estimates held until their ground truth has arrived, so that each is scored when it can be.

    The truth and the pose of one stamp reach a subscriber over different routes (ingest and filter), so
    the pose can come first; it waits at most ``wait_s`` for its truth.

    Args:
        matcher: the ground truth received so far.
        wait_s: longest hold of an estimate, seconds.
    """

    def __init__(self, matcher: GroundTruthMatcher, wait_s: float = 0.5) -> None:
        self.matcher = matcher
        self.wait_s = wait_s
        self._pending: collections.deque[tuple[float, PoseEstimate]] = collections.deque()

    def add(self, estimate: PoseEstimate, arrived_at: float) -> None:
        """Hold an estimate that arrived at ``arrived_at`` (monotonic seconds)."""
        self._pending.append((arrived_at, estimate))

    def release(self, now: float) -> list[tuple[PoseEstimate, PoseError | None]]:
        """The held estimates, oldest first, whose truth is settled or that waited ``wait_s``, with their errors."""
        released = []
        while self._pending and (self.matcher.settled(self._pending[0][1]) or now - self._pending[0][0] >= self.wait_s):
            estimate = self._pending.popleft()[1]
            released.append((estimate, self.matcher.error(estimate)))
        return released
