"""Recent odometry poses: increments for prediction and the carry to an image stamp."""

from __future__ import annotations

import bisect

import torch

from locnerf.geometry.se3 import interpolate_pose, relative_pose


class OdometryHistory:
    """Stamped ``T_odom_body`` (4, 4) float64 over the last ``horizon`` seconds.

    Args:
        horizon: seconds of history kept (images older than this cannot be carried).
    """

    def __init__(self, horizon: float) -> None:
        self.horizon = horizon
        self._stamps: list[float] = []
        self._poses: list[torch.Tensor] = []

    @property
    def latest_stamp(self) -> float | None:
        """Stamp of the newest odometry, None when empty."""
        return self._stamps[-1] if self._stamps else None

    @property
    def latest_pose(self) -> torch.Tensor | None:
        """The newest ``T_odom_body`` (4, 4), None when empty."""
        return self._poses[-1] if self._poses else None

    def clear(self) -> None:
        """Forget everything (e.g. after the odometry source restarted)."""
        self._stamps.clear()
        self._poses.clear()

    def append(self, stamp: float, T_odom_body: torch.Tensor) -> torch.Tensor | None:
        """Record a pose; returns the increment ``T_prev_curr`` (4, 4) from the previous one, or None.

        Raises:
            ValueError: if ``stamp`` is not newer than the latest one.
        """
        pose = T_odom_body.double()
        if self._stamps and stamp <= self._stamps[-1]:
            raise ValueError(f"odometry stamp {stamp} is not after the previous one {self._stamps[-1]}")
        increment = relative_pose(self._poses[-1], pose) if self._poses else None
        self._stamps.append(stamp)
        self._poses.append(pose)
        while self._stamps[0] < stamp - self.horizon:
            self._stamps.pop(0)
            self._poses.pop(0)
        return increment

    def pose_at(self, stamp: float) -> torch.Tensor:
        """Odometry pose at ``stamp`` (4, 4), geodesically interpolated between neighbours.

        Raises:
            ValueError: a stamp outside the history (older than kept or newer than the latest).
        """
        if not self._stamps or not self._stamps[0] <= stamp <= self._stamps[-1]:
            span = f"[{self._stamps[0]}, {self._stamps[-1]}]" if self._stamps else "(empty)"
            raise ValueError(f"stamp {stamp} is outside the odometry history {span}")
        index = bisect.bisect_left(self._stamps, stamp)
        if self._stamps[index] == stamp:
            return self._poses[index]
        t0, t1 = self._stamps[index - 1], self._stamps[index]
        return interpolate_pose(self._poses[index - 1], self._poses[index], (stamp - t0) / (t1 - t0))

    def carry_to(self, stamp: float) -> torch.Tensor | None:
        """Increment (4, 4) from the latest odometry pose back to the pose at ``stamp``.

        None when ``stamp`` is at or after the latest odometry (no motion known yet).
        """
        latest = self.latest_stamp
        if latest is None or stamp >= latest:
            return None
        return relative_pose(self._poses[-1], self.pose_at(stamp))
