"""Where the filter thread spends its time, and how long odometry waits for it.

The pose stream's jitter is the odometry's arrival jitter plus the time each odometry message waits
for the filter thread (busy merging, starting an update, publishing particles) plus the pose work
itself. :class:`ThreadTimings` keeps the recent durations of each kind of work and the odometry
wait (callback enqueue → handling starts), and summarises them in one log line.
"""

from __future__ import annotations

import collections

import numpy as np


class ThreadTimings:
    """Recent durations (seconds) per kind of work, and the odometry wait.

    Args:
        keep: samples kept per kind (the newest).
    """

    def __init__(self, keep: int = 1024) -> None:
        if keep < 1:
            raise ValueError(f"keep {keep}: expected >= 1")
        self.keep = keep
        self.work: dict[str, collections.deque[float]] = {}
        self.odometry_wait: collections.deque[float] = collections.deque(maxlen=keep)

    def record(self, kind: str, seconds: float) -> None:
        """One piece of work of ``kind`` took ``seconds``."""
        self.work.setdefault(kind, collections.deque(maxlen=self.keep)).append(seconds)

    def record_wait(self, seconds: float) -> None:
        """An odometry message waited ``seconds`` between its arrival and its handling."""
        self.odometry_wait.append(seconds)

    def summary(self) -> str:
        """``odometry wait p50/p99/max`` and ``p50/p99/max`` of each kind of work, milliseconds."""

        def stats(samples: collections.deque[float]) -> str:
            values = 1000.0 * np.asarray(samples)
            return f"{np.percentile(values, 50):.2f}/{np.percentile(values, 99):.2f}/{values.max():.2f}"

        parts = [f"odometry wait {stats(self.odometry_wait)}"] if self.odometry_wait else []
        parts += [f"{kind} {stats(samples)}" for kind, samples in sorted(self.work.items())]
        return "filter thread ms (p50/p99/max): " + ("; ".join(parts) if parts else "idle")
