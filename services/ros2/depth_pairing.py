"""Pairing colour images with depth images by stamp, for cameras that publish the two separately.

An RGB-D camera driver publishes its colour and depth images on two topics; a depth image
registered to the colour camera (RealSense's ``aligned_depth_to_color``) is computed from the
colour frame's depth and usually arrives a few milliseconds after the colour image. The consumer
thread therefore holds the newest colour image until its depth has come:

* a colour image is paired with the buffered depth image nearest to it in stamp, among those within
  ``tolerance`` seconds;
* the pairing is final once a depth image stamped at or after the colour image has arrived (depth
  images arrive in stamp order, so no nearer one can follow); until then the colour image waits,
  at most ``max_wait`` wall-clock seconds, and then goes with the nearest depth within tolerance,
  or alone (counted in :attr:`DepthPairing.without_depth`);
* only the newest colour image waits: a newer one replaces it, and the older one is dropped (counted
  in :attr:`DepthPairing.replaced`), as the filter keeps only the newest image. The newer one takes
  over the older one's deadline, so that images keep flowing when depth images stop coming: the
  newest colour image then goes alone every ``max_wait`` seconds, instead of each being replaced
  by the next before its own wait is over;
* the ``capacity`` newest depth images are kept; once a colour image is released, depth images
  that no later colour image can match (older than its stamp minus the tolerance, or at and before
  the one paired with it) are dropped.

Pure logic: no threads and no I/O; the clock is injected. One thread calls everything.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

Colour = TypeVar("Colour")
Depth = TypeVar("Depth")

STAMP_RESOLUTION = 1e-9
"""Stamps are whole nanoseconds: differences within this of the tolerance count as within it."""


@dataclass(frozen=True)
class _Pending(Generic[Colour]):
    stamp: float
    colour: Colour
    deadline: float


class DepthPairing(Generic[Colour, Depth]):
    """Holds the newest colour image until the depth image of its stamp has arrived (module docstring).

    Args:
        tolerance: largest stamp difference of a pair, seconds (>= 0).
        max_wait: longest wait of a colour image for its depth, wall-clock seconds (>= 0; 0: pair
            only with a depth image that has already arrived).
        clock: monotonic wall-clock seconds.
        capacity: depth images kept (>= 1).
    """

    def __init__(self, tolerance: float, max_wait: float, clock: Callable[[], float] = time.monotonic, capacity: int = 16) -> None:
        if tolerance < 0 or max_wait < 0 or capacity < 1:
            raise ValueError(f"depth pairing: tolerance {tolerance} s, max_wait {max_wait} s, capacity {capacity}: expected >= 0, >= 0 and >= 1")
        self.tolerance = tolerance
        self.max_wait = max_wait
        self.clock = clock
        self._depths: collections.deque[tuple[float, Depth]] = collections.deque(maxlen=capacity)
        self._pending: _Pending[Colour] | None = None
        self.paired = 0
        self.without_depth = 0
        self.replaced = 0

    def add_colour(self, stamp: float, colour: Colour) -> None:
        """A colour image stamped ``stamp`` seconds: it waits for its depth, replacing (dropping) a waiting
        one, whose deadline it keeps."""
        if self._pending is None:
            deadline = self.clock() + self.max_wait
        else:
            self.replaced += 1
            deadline = self._pending.deadline
        self._pending = _Pending(stamp, colour, deadline)

    def add_depth(self, stamp: float, depth: Depth) -> None:
        """A depth image stamped ``stamp`` seconds (the oldest kept one is dropped when ``capacity`` are kept)."""
        self._depths.append((stamp, depth))

    def time_left(self) -> float | None:
        """Seconds until the waiting colour image goes without its depth (0 when due); None when none waits."""
        return None if self._pending is None else max(0.0, self._pending.deadline - self.clock())

    def release(self) -> tuple[Colour, Depth | None] | None:
        """The waiting colour image and its depth image (None: none within tolerance) once the pairing
        is final or the wait is over; None while it waits, or when no colour image waits."""
        pending = self._pending
        if pending is None:
            return None
        final = any(stamp >= pending.stamp for stamp, _ in self._depths)
        if not final and self.clock() < pending.deadline:
            return None
        self._pending = None
        nearest = self._nearest(pending.stamp)
        if nearest is None:
            self.without_depth += 1
            self._drop_depths_before(pending.stamp - self.tolerance)
            return pending.colour, None
        stamp, depth = nearest
        self.paired += 1
        self._drop_depths_before(stamp, inclusive=True)
        return pending.colour, depth

    def _nearest(self, stamp: float) -> tuple[float, Depth] | None:
        within = [
            (abs(depth_stamp - stamp), index)
            for index, (depth_stamp, _) in enumerate(self._depths)
            if abs(depth_stamp - stamp) <= self.tolerance + STAMP_RESOLUTION
        ]
        return self._depths[min(within)[1]] if within else None

    def _drop_depths_before(self, stamp: float, inclusive: bool = False) -> None:
        kept = [(depth_stamp, depth) for depth_stamp, depth in self._depths if depth_stamp > stamp or (depth_stamp == stamp and not inclusive)]
        self._depths.clear()
        self._depths.extend(kept)
