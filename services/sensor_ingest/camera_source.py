"""A live OpenCV camera or a video file as the image source; odometry comes from the robot's VIO
on ``sensors/odom`` (stamped with the same clock: wall time for a live camera).

Stamps. A video file's frames are stamped with their own position in the file
(``CAP_PROP_POS_MSEC`` after the frame is read, seconds). A live camera's frames are stamped with
their capture time: OpenCV reports the driver's buffer timestamp as ``CAP_PROP_POS_MSEC`` (V4L2:
the kernel's timestamp of the frame, on CLOCK_MONOTONIC), which :func:`capture_stamp` moves to wall
time. Where the backend gives no such timestamp, a frame is stamped when ``grab()`` returns (logged
once): later than the capture by the driver's latency, but before decoding. The time after
``read()`` returned, used before, also counted the decoding and the frames waiting in the driver.

Stale frames. A live camera is asked to buffer a single frame (``CAP_PROP_BUFFERSIZE`` = 1, which
V4L2 and a few other backends honour), and a grabbed frame whose capture stamp is more than
``STALE_PERIODS`` frame periods old is skipped for the next one, at most ``MAX_SKIPPED`` in a row
(the number of buffers OpenCV's V4L2 backend queues): a consumer that fell behind gets the newest
frame rather than the driver's backlog.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import ConfigError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import ImageEvent

logger = logging.getLogger(__name__)

STALE_PERIODS = 1.5
"""A live frame captured more than this many frame periods before it was grabbed is skipped (a newer one is waiting)."""

MAX_SKIPPED = 4
"""Stale frames skipped in a row at most (OpenCV's V4L2 backend queues 4 buffers)."""

MAX_CAPTURE_AGE = 10.0
"""Seconds: a capture timestamp further than this before the clock it is compared with is not on that clock."""


class CameraSourceConfig(BaseModel):
    """Which capture device or file, and its calibration."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    device: str = Field("0", description="Camera index (e.g. '0'), device path (/dev/video0), stream URL, or the path of a video file.")
    live: bool | None = Field(
        None,
        description="Whether the device is a live camera (frames stamped with their capture time on the wall clock, stale buffered frames "
        "skipped) or a recording (frames stamped with their position in it); None: live for a camera index, a /dev/ path or a URL.",
    )
    intrinsics: PinholeIntrinsics | None = Field(None, description="Calibration of the (undistorted) frames; required.")


def is_live(config: CameraSourceConfig) -> bool:
    """Whether ``config.device`` is read as a live camera (see ``CameraSourceConfig.live``)."""
    if config.live is not None:
        return config.live
    return config.device.isdigit() or config.device.startswith("/dev/") or "://" in config.device


def capture_stamp(position_ms: float, wall_now: float, monotonic_now: float) -> float | None:
    """A live capture's own timestamp, ``CAP_PROP_POS_MSEC`` in milliseconds, as wall-clock seconds.

    The timestamp is on the monotonic clock (V4L2's usual) when it lies within ``MAX_CAPTURE_AGE``
    before ``monotonic_now``, and then moved by the clocks' offset; on the wall clock when it lies as
    close before ``wall_now``. None when it is on neither (0 before a first frame, or a backend that
    reports a stream position instead).
    """
    seconds = position_ms / 1000.0
    if 0.0 <= monotonic_now - seconds <= MAX_CAPTURE_AGE:
        return wall_now - (monotonic_now - seconds)
    if 0.0 <= wall_now - seconds <= MAX_CAPTURE_AGE:
        return seconds
    return None


def _file_frames(capture: cv2.VideoCapture) -> Iterator[tuple[float, np.ndarray]]:
    """(stamp in the file's time, BGR frame) of every frame of a recording."""
    while True:
        ok, frame = capture.read()
        if not ok:
            return
        yield capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, frame


def _live_frames(capture: cv2.VideoCapture, wall: Callable[[], float], monotonic: Callable[[], float]) -> Iterator[tuple[float, np.ndarray]]:
    """(capture stamp on the wall clock, BGR frame) of a live camera, stale buffered frames skipped (module docstring)."""
    if not capture.set(cv2.CAP_PROP_BUFFERSIZE, 1):
        logger.info("camera: the backend does not take CAP_PROP_BUFFERSIZE = 1; stale frames are skipped by their capture stamps")
    fps = capture.get(cv2.CAP_PROP_FPS)
    stale_after = STALE_PERIODS / fps if fps > 0 else math.inf
    skipped = 0
    warned = False
    while capture.grab():
        grabbed_at = wall()
        stamp = capture_stamp(capture.get(cv2.CAP_PROP_POS_MSEC), grabbed_at, monotonic())
        if stamp is not None and grabbed_at - stamp > stale_after and skipped < MAX_SKIPPED:
            skipped += 1
            continue
        skipped = 0
        ok, frame = capture.retrieve()
        if not ok:
            return
        if stamp is None:
            if not warned:
                logger.warning("camera: the backend gives no capture timestamps; frames are stamped when grabbed (later by the driver's latency)")
                warned = True
            stamp = grabbed_at
        yield stamp, frame


def camera_events(config: CameraSourceConfig, clock: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic) -> Iterator[ImageEvent]:
    """Frames as RGB image events until the capture ends (stamps: module docstring).

    Args:
        clock: wall-clock seconds, the clock of a live camera's stamps (and of the robot's odometry).
        monotonic: the monotonic clock a live camera's capture timestamps are compared with.

    Raises:
        ConfigError: no intrinsics, or a device that cannot be opened.
        ValueError: frames of another size than the intrinsics'.
    """
    if config.intrinsics is None:
        raise ConfigError("source = 'camera' needs camera.intrinsics (fx, fy, cx, cy, width, height)")
    live = is_live(config)
    capture = cv2.VideoCapture(int(config.device) if config.device.isdigit() else config.device)
    if not capture.isOpened():
        raise ConfigError(f"camera device {config.device!r}: cannot be opened (expected a camera index or a readable video file)")
    size = (config.intrinsics.height, config.intrinsics.width)
    try:
        for stamp, frame in _live_frames(capture, clock, monotonic) if live else _file_frames(capture):
            if frame.shape[:2] != size:
                raise ValueError(f"camera {config.device!r}: frame of {frame.shape[1]}×{frame.shape[0]}, expected {size[1]}×{size[0]} from the intrinsics")
            yield ImageEvent(stamp, cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), config.intrinsics)
    finally:
        capture.release()
