"""The filter's last pose across restarts: restored from the state file at start, saved off the pose path.

Without a state file (``FilterLoopConfig.state_file`` empty) nothing is restored or saved.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from locnerf_services.filter_loop.state_file import SavedPose, load_pose
from locnerf_services.filter_loop.state_writer import StateWriter

logger = logging.getLogger(__name__)


class PosePersistence:
    """The state file and its writer thread.

    Args:
        state_file: path of the state file; empty for none.
        save_rate: saves per second at most (> 0).
    """

    def __init__(self, state_file: str, save_rate: float) -> None:
        self.path = Path(state_file) if state_file else None
        self.writer = StateWriter(self.path, save_rate) if self.path is not None else None

    def restore(self) -> SavedPose | None:
        """The saved pose to resume from, or None (no state file, or none saved or readable)."""
        saved = load_pose(self.path) if self.path is not None else None
        if saved is not None:
            logger.info("resuming from the saved pose of stamp %.3f (%s)", saved.stamp, self.path)
        return saved

    def offer(self, stamp: float, T_world_cam: torch.Tensor, covariance: torch.Tensor, T_odom_cam: torch.Tensor) -> None:
        """Hand a published pose to the writer: metric ``T_world_cam`` (4, 4), its covariance (6, 6) and
        the odometry pose ``T_odom_cam`` (4, 4) of the same stamp, float64 (copied: the writer thread
        never sees the filter's own tensors)."""
        if self.writer is not None:
            self.writer.offer(SavedPose(stamp, T_world_cam.clone(), covariance.clone(), T_odom_cam.clone()))

    @property
    def failures(self) -> int:
        """Saves that failed so far."""
        return self.writer.failures if self.writer is not None else 0

    def close(self) -> None:
        """Stop the writer after writing the last pose offered."""
        if self.writer is not None:
            self.writer.close()
