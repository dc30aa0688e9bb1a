"""The ingest service: sensor events to wire messages, paced in (scaled) real time."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator

from locnerf.messages import keys
from locnerf.messages.codec import encode, encode_image
from locnerf.messages.schemas import DepthHeader, ImageHeader, Odometry, PoseStamped
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent

logger = logging.getLogger(__name__)


def _stamp(event: SensorEvent) -> dict[str, float | int]:
    """The wire stamp of an event: its whole nanoseconds when the source gave them, else its float seconds."""
    return {"stamp": event.stamp} if event.stamp_ns is None else {"stamp_ns": event.stamp_ns}


def event_message(robot_id: str, event: SensorEvent, camera_frame: str = "camera") -> tuple[str, bytes]:
    """(key, payload) of one event."""
    if isinstance(event, OdometryEvent):
        return keys.key(robot_id, keys.ODOMETRY), encode(Odometry(**_stamp(event), frame_id="odom", T_odom_body=event.T_odom_body.tolist()))
    if isinstance(event, GroundTruthEvent):
        return keys.key(robot_id, keys.GROUND_TRUTH), encode(PoseStamped(**_stamp(event), frame_id="map", T_world_cam=event.T_world_cam.tolist()))
    if isinstance(event, ImageEvent):
        height, width = event.pixels.shape[:2]
        depth = event.depth
        depth_header = None
        if depth is not None:
            offset = None if depth.T_cam_depth is None else depth.T_cam_depth.tolist()
            depth_header = DepthHeader(width=depth.millimetres.shape[1], height=depth.millimetres.shape[0], intrinsics=depth.intrinsics, T_cam_depth=offset)
        header = ImageHeader(
            **_stamp(event), frame_id=camera_frame, encoding="rgb8", width=width, height=height, intrinsics=event.intrinsics, depth=depth_header
        )
        return keys.key(robot_id, keys.IMAGE), encode_image(header, event.pixels, None if depth is None else depth.millimetres)
    raise TypeError(f"unknown sensor event {type(event).__name__}")


class Pacer:
    """Releases events at their stamps divided by ``speed`` (0: as fast as possible).

    Args:
        speed: sensor seconds per wall second (1 real time, 2 twice as fast, 0 no waiting).
        clock: monotonic seconds; sleep: waits seconds (both injectable for tests).
    """

    def __init__(self, speed: float = 1.0, clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        if speed < 0:
            raise ValueError(f"speed {speed}: expected >= 0 (0 = as fast as possible)")
        self.speed, self.clock, self.sleep = speed, clock, sleep

    def paced(self, events: Iterable[SensorEvent], should_stop: Callable[[], bool] = lambda: False) -> Iterator[SensorEvent]:
        """Yield events, waiting until each one's time has come."""
        start_wall: float | None = None
        start_stamp = 0.0
        for event in events:
            if should_stop():
                return
            if self.speed > 0:
                if start_wall is None:
                    start_wall, start_stamp = self.clock(), event.stamp
                delay = start_wall + (event.stamp - start_stamp) / self.speed - self.clock()
                if delay > 0:
                    self.sleep(delay)
            yield event


class ProgressLog:
    """A line of progress every ``interval`` wall seconds while events are sent: events and camera
    frames sent in all, their rates since the previous line, wall seconds streaming and the sensor
    stamp reached (0: no lines).

    Args:
        interval: wall seconds between lines. clock: monotonic seconds (injectable for tests).
    """

    def __init__(self, interval: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval, self.clock = interval, clock
        self.events = self.frames = 0
        self._start = self._last = clock()
        self._last_events = self._last_frames = 0

    def sent(self, event: SensorEvent) -> None:
        """Count ``event`` as sent; log the line when one is due."""
        self.events += 1
        self.frames += isinstance(event, ImageEvent)
        now = self.clock()
        if self.interval <= 0 or now - self._last < self.interval:
            return
        span = now - self._last
        logger.info(
            "ingest: %d events sent (%d frames) in %.0f s; last %.0f s: %.1f events/s, %.2f frames/s; sensor time %.1f s",
            self.events,
            self.frames,
            now - self._start,
            span,
            (self.events - self._last_events) / span,
            (self.frames - self._last_frames) / span,
            event.stamp,
        )
        self._last, self._last_events, self._last_frames = now, self.events, self.frames
