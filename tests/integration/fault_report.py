"""Figures of the fault tests: pose losses from stamps, and a JSON-lines report for docs/RELIABILITY.md.

With ``LOCNERF_FAULT_REPORT=<file>`` set, every fault test appends one JSON line of what it
measured (counts, poses lost, gaps); without it nothing is written. The tests assert only
liveness; the figures go into the docs.
"""

from __future__ import annotations

import json
import os

import torch

from locnerf.messages.schemas import PoseEstimate

ODOMETRY_RATE = 15.0


def poses_lost(poses: list[PoseEstimate], start: float, end: float, rate: float = ODOMETRY_RATE) -> int:
    """Odometry periods in [start, end] (sensor seconds) with no pose: the stream is one pose per
    odometry message, so a stamp gap of k periods lost k - 1 poses."""
    stamps = sorted({pose.stamp for pose in poses if start <= pose.stamp <= end})
    return sum(max(0, round((b - a) * rate) - 1) for a, b in zip(stamps, stamps[1:]))


def covariance_trace(pose: PoseEstimate) -> float:
    """Trace of a pose's 6×6 covariance (rad² + m²)."""
    return float(torch.tensor(pose.covariance, dtype=torch.float64).diagonal().sum())


def report(test: str, **figures: object) -> None:
    """Append ``{"test": test, **figures}`` to $LOCNERF_FAULT_REPORT, if set."""
    path = os.environ.get("LOCNERF_FAULT_REPORT")
    if path:
        with open(path, "a") as file:
            file.write(json.dumps({"test": test, **figures}) + "\n")
