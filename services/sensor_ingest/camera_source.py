"""A live OpenCV camera or a video file as the image source; odometry comes from the robot's VIO
on ``sensors/odom`` (stamped with the same clock: wall time for a live camera)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import cv2
from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import ConfigError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import ImageEvent


class CameraSourceConfig(BaseModel):
    """Which capture device or file, and its calibration."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    device: str = Field("0", description="Camera index (e.g. '0') or the path of a video file.")
    intrinsics: PinholeIntrinsics | None = Field(None, description="Calibration of the (undistorted) frames; required.")


def camera_events(config: CameraSourceConfig, clock=time.time) -> Iterator[ImageEvent]:
    """Frames as RGB image events until the capture ends.

    A video file's frames are stamped with their position in the file (seconds); a live camera's
    with ``clock()`` at capture.

    Raises:
        ConfigError: no intrinsics, or a device that cannot be opened.
        ValueError: frames of another size than the intrinsics'.
    """
    if config.intrinsics is None:
        raise ConfigError("source = 'camera' needs camera.intrinsics (fx, fy, cx, cy, width, height)")
    live = config.device.isdigit()
    capture = cv2.VideoCapture(int(config.device) if live else config.device)
    if not capture.isOpened():
        raise ConfigError(f"camera device {config.device!r}: cannot be opened (expected a camera index or a readable video file)")
    size = (config.intrinsics.height, config.intrinsics.width)
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            if frame.shape[:2] != size:
                raise ValueError(f"camera {config.device!r}: frame of {frame.shape[1]}×{frame.shape[0]}, expected {size[1]}×{size[0]} from the intrinsics")
            stamp = clock() if live else capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            yield ImageEvent(stamp, cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), config.intrinsics)
    finally:
        capture.release()
