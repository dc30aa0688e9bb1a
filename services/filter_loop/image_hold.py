"""Images stamped after the newest odometry wait until odometry passes their stamp.

An update weighs its image against the particles carried to the image's stamp with the
interpolated odometry (:meth:`OdometryHistory.carry_to`). For an image newer than the newest
odometry that carry is unknown, and weighing the particles at the odometry's stamp instead biases
the update by the motion in between (v·Δt along the motion: 3 cm at 0.5 m/s for one 15 Hz period).
Real VIO publishes after the camera, so this is the common case: such an image is held here until
odometry at or after its stamp has arrived, for at most ``wait`` seconds of the filter's clock.

An image whose wait is over is dropped and counted, not weighed at the newest odometry: after the
wait the bias would be at least v·``wait``, larger than the one this hold exists to remove; and
when no odometry comes at all no pose is published either (poses are per odometry message), so an
update from it could only be seen after odometry resumes, when a newer image is there to use.

Pure logic: no threads and no I/O; the clock is passed in. One thread calls everything.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from locnerf.messages.schemas import ImageHeader

Frame = tuple[ImageHeader, np.ndarray, np.ndarray | None]
"""A decoded image frame: header, RGB pixels (H, W, 3) uint8, depth (Hd, Wd) uint16 millimetres or None."""

HELD_IMAGES = 8
"""Images held at once (a newer one drops the oldest, counted as replaced): enough for VIO that lags
the camera by several frame periods (30 Hz images, 0.25 s behind), while bounding the memory held."""


@dataclass(frozen=True, eq=False)
class _Held:
    frame: Frame
    arrived: float


class ImageHold:
    """Holds images newer than the newest odometry until odometry reaches their stamps (module docstring).

    Args:
        wait: longest hold of an image, seconds of the filter's clock (> 0).
        capacity: images held at once (>= 1).

    Counters: ``released`` (held images handed on once odometry reached their stamp), ``expired``
    (dropped when their wait was over), ``replaced`` (dropped for a newer one, held or handed on).
    """

    def __init__(self, wait: float, capacity: int = HELD_IMAGES) -> None:
        if wait <= 0 or capacity < 1:
            raise ValueError(f"image hold: wait {wait} s and capacity {capacity}: expected > 0 and >= 1")
        self.wait = wait
        self._held: collections.deque[_Held] = collections.deque(maxlen=capacity)
        self.released = 0
        self.expired = 0
        self.replaced = 0

    def __len__(self) -> int:
        return len(self._held)

    def hold(self, frame: Frame, now: float) -> None:
        """Hold ``frame`` (arrived at ``now``); the oldest held one is dropped when ``capacity`` are held."""
        if len(self._held) == self._held.maxlen:
            self.replaced += 1
        self._held.append(_Held(frame, now))

    def release(self, latest_odometry: float | None, now: float) -> Frame | None:
        """The newest held image stamped at or before ``latest_odometry`` (older such ones are dropped as
        replaced), None when none is; held images whose wait is over by ``now`` are dropped as expired."""
        covered: list[_Held] = []
        waiting: list[_Held] = []
        for held in self._held:
            if latest_odometry is not None and held.frame[0].stamp <= latest_odometry:
                covered.append(held)
            elif now - held.arrived <= self.wait:
                waiting.append(held)
            else:
                self.expired += 1
        self._held = collections.deque(waiting, maxlen=self._held.maxlen)
        if not covered:
            return None
        self.released += 1
        self.replaced += len(covered) - 1
        return max(covered, key=lambda held: held.frame[0].stamp).frame
