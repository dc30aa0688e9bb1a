"""The OpenCV camera source: stamps of recordings and of live cameras, stale buffered frames skipped."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from locnerf.render.camera import PinholeIntrinsics
from locnerf_services.sensor_ingest.camera_source import CameraSourceConfig, camera_events, capture_stamp, is_live

INTRINSICS = PinholeIntrinsics(fx=30.0, fy=30.0, cx=16.0, cy=12.0, width=32, height=24)


def _clip(path: Path, frames: int = 6, fps: float = 10.0) -> str:
    """A video file of ``frames`` frames at ``fps``, frame k red 40·k (BGR order in the file)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (INTRINSICS.width, INTRINSICS.height))
    for k in range(frames):
        frame = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
        frame[..., 2] = 40 * k
        writer.write(frame)
    writer.release()
    return str(path)


def _reds(events) -> list[int]:
    """The frame index k of each event, from its red level 40·k."""
    return [round(float(event.pixels[..., 0].mean()) / 40) for event in events]


def test_a_recording_is_stamped_with_each_frame_s_own_time(tmp_path):
    events = list(camera_events(CameraSourceConfig(device=_clip(tmp_path / "clip.avi"), intrinsics=INTRINSICS)))
    assert [event.stamp for event in events] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4, 0.5], abs=1e-9)
    assert _reds(events) == [0, 1, 2, 3, 4, 5]


def test_a_live_capture_is_stamped_with_its_capture_time_and_stale_frames_are_skipped(tmp_path):
    # The recording stands in for a driver whose buffer timestamps (CAP_PROP_POS_MSEC) are on the
    # monotonic clock: frames captured at monotonic 0.0 .. 0.5 s, all already waiting at 0.5 s.
    config = CameraSourceConfig(device=_clip(tmp_path / "clip.avi"), live=True, intrinsics=INTRINSICS)
    events = list(camera_events(config, clock=lambda: 1000.5, monotonic=lambda: 0.5))
    # Frames 0-3 are more than 1.5 periods (0.15 s) old when grabbed: skipped; 4 and 5 carry their
    # capture times on the wall clock (wall 1000.5 is monotonic 0.5), not the time they were read.
    assert [event.stamp for event in events] == pytest.approx([1000.4, 1000.5], abs=1e-9)
    assert _reds(events) == [4, 5]


def test_a_live_capture_without_capture_timestamps_is_stamped_when_grabbed(tmp_path):
    config = CameraSourceConfig(device=_clip(tmp_path / "clip.avi"), live=True, intrinsics=INTRINSICS)
    grabs = iter(range(100))
    events = list(camera_events(config, clock=lambda: 2000.0 + next(grabs), monotonic=lambda: 5e4))
    assert [event.stamp for event in events] == [2000.0, 2001.0, 2002.0, 2003.0, 2004.0, 2005.0] and _reds(events) == [0, 1, 2, 3, 4, 5]


def test_capture_stamps_are_told_apart_by_clock_and_devices_by_name():
    assert capture_stamp(99_500.0, wall_now=1_700_000_000.0, monotonic_now=100.0) == pytest.approx(1_699_999_999.5)  # monotonic
    assert capture_stamp(1_699_999_999_500.0, wall_now=1_700_000_000.0, monotonic_now=100.0) == pytest.approx(1_699_999_999.5)  # wall
    assert capture_stamp(0.0, wall_now=1_700_000_000.0, monotonic_now=100.0) is None  # before a first frame
    assert [is_live(CameraSourceConfig(device=device)) for device in ("0", "/dev/video2", "rtsp://cam/stream", "clip.mp4")] == [True, True, True, False]
