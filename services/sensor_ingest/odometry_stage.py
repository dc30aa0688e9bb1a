"""Online RGB-D odometry in the ingest: each camera frame becomes an odometry step as it arrives.

A camera without VIO (a RealSense-class RGB-D camera) gives colour and depth frames, no odometry.
:class:`OdometryStage` turns them into odometry on its own thread: :meth:`OdometryStage.submit`
hands a frame over without waiting (the release of the other events and the pose stream never wait
for it), the thread decimates the depth image to at most ``max_width`` pixels across (320×240 of a
640×480 camera), resamples the colour image onto that grid through the two cameras' placement
(:func:`~locnerf.odometry.rgbd.register_colour`), aligns it to the last tracked frame with OpenCV's
dense odometry (:class:`~locnerf.odometry.rgbd.RgbdOdometry`) and publishes the colour camera's pose
``T_odom_cam = T_odom_depth · T_depth_cam`` at the frame's stamp, at the camera's rate.

A frame the odometry fails on is a gap (counted by reason, nothing published: the filter widens
its prediction noise across the longer increment); so is a frame that finds the stage still busy
with ``queue_frames`` earlier ones (``dropped``: the stage cannot keep up, as a camera driver drops
frames). OpenCV releases the interpreter lock while it computes, so the thread runs beside the
pacer; ``threads`` caps OpenCV's own threads (1: one core).

:meth:`OdometryStage.counters` reports, as integers for the ingest's status: frames, poses, resumptions, gaps
(and per reason), the time per frame (wall and the thread's CPU time, microseconds: median,
min, max, 10th and 90th percentiles), the latency from hand-over to publication and the achieved
rate of published poses (millihertz).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.se3 import pose_inverse
from locnerf.odometry.rgbd import RgbdOdometry, RgbdOdometryConfig, register_colour
from locnerf.sim.events import OdometryEvent, RgbdFrameEvent

logger = logging.getLogger(__name__)

_STOP = object()
_MAX_SAMPLES = 1 << 16  # per-frame timings kept for the report (an hour at 15 Hz)


class OnlineOdometryConfig(BaseModel):
    """The ingest's online RGB-D odometry (used when its source gives RGB-D frames for odometry)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    rgbd: RgbdOdometryConfig = Field(default_factory=RgbdOdometryConfig, description="OpenCV odometry variant and the checks that make gaps.")
    max_width: int = Field(
        320,
        ge=16,
        description="Depth images wider are decimated by the smallest integer stride that brings them to at most this width "
        "(a 640×480 camera: 320×240, the size the odometry was measured at); the colour image is resampled onto that grid.",
    )
    ros2_frames: bool = Field(
        False,
        description="source = 'ros2': compute the odometry from the paired colour and depth frames (needs ros2.depth_topic, "
        "and ros2.odometry_topic = '' so that no robot odometry mixes with it).",
    )
    queue_frames: int = Field(2, ge=1, description="Frames waiting for the stage at most; a frame finding it full is dropped (a gap, 'dropped').")
    threads: int = Field(1, ge=1, description="OpenCV threads (cv2.setNumThreads) of the ingest process: 1 computes on one core.")
    nice: int = Field(0, ge=0, le=19, description="Niceness added to the stage's thread (0: the ingest's priority).")


def _percentiles(samples: list[float], name: str) -> dict[str, int]:
    """Median, min, max, p10 and p90 of ``samples`` (seconds) as whole microseconds under ``<name>_us_*``."""
    if not samples:
        return {}
    values = np.percentile(np.asarray(samples) * 1e6, [50, 0, 100, 10, 90])
    return {f"{name}_us_{label}": int(round(v)) for label, v in zip(("median", "min", "max", "p10", "p90"), values)}


class OdometryStage:
    """A thread turning :class:`RgbdFrameEvent` into :class:`OdometryEvent` (see the module).

    Args:
        config: odometry settings, queue size, threads and niceness.
        publish: sends one odometry event (called from the stage's thread).
        clock: monotonic seconds (hand-over, publication and the rate).
    """

    def __init__(self, config: OnlineOdometryConfig, publish: Callable[[OdometryEvent], None], clock: Callable[[], float] = time.monotonic) -> None:
        cv2.setNumThreads(config.threads)  # process-wide: set only when the ingest runs a stage
        self.config, self.publish, self.clock = config, publish, clock
        self._queue: queue.Queue[object] = queue.Queue(maxsize=config.queue_frames)
        self._odometry: RgbdOdometry | None = None
        self._lock = threading.Lock()
        self.dropped = 0
        self.published = 0
        self._frames = 0  # frames the odometry saw, its gaps by reason and how often it resumed, copied after each step
        self._resumed = 0
        self._reasons: dict[str, int] = {}
        self._wall: list[float] = []
        self._cpu: list[float] = []
        self._latency: list[float] = []
        self._published_at: list[float] = []
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="ingest-odometry", daemon=True)
        self._thread.start()

    def submit(self, event: RgbdFrameEvent) -> None:
        """Hand ``event`` to the stage without waiting; a full queue drops it (a gap).

        Raises:
            RuntimeError: the stage's thread failed (its error chained).
        """
        if self._failure is not None:
            raise RuntimeError("the online odometry failed") from self._failure
        try:
            self._queue.put_nowait((event, self.clock()))
        except queue.Full:
            with self._lock:
                self.dropped += 1
            logger.info("odometry gap at %.3f s (dropped): the stage is still busy with %d frames", event.stamp, self.config.queue_frames)

    def _run(self) -> None:
        if self.config.nice:
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, 0) + self.config.nice)
            except OSError as error:
                logger.warning("odometry thread keeps its priority: %s", error)
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            event, handed_over = item  # type: ignore[misc]
            try:
                self._step(event, handed_over)
            except BaseException as error:  # noqa: BLE001 - re-raised by submit and close in the ingest's thread
                self._failure = error
                logger.exception("online odometry failed at %.3f s", event.stamp)
                return

    def _step(self, event: RgbdFrameEvent, handed_over: float) -> None:
        wall, cpu = time.perf_counter(), time.thread_time()
        frame = event.frame
        depth = frame.depth
        if depth is None:
            raise ValueError(f"RGB-D frame at {event.stamp} s without a depth image")
        stride = -(-depth.intrinsics.width // self.config.max_width)
        grid = depth.intrinsics.decimated(stride)
        if self._odometry is None:  # one chain of poses: a frame of another size later is refused by step
            self._odometry = RgbdOdometry(self.config.rgbd, grid)
        depth_m = depth.millimetres[::stride, ::stride].astype(np.float32) * np.float32(1e-3)
        T_cam_depth = None if depth.T_cam_depth is None else depth.T_cam_depth.double().numpy()
        pose = self._odometry.step(event.stamp, register_colour(frame.pixels, frame.intrinsics, grid, depth_m, T_cam_depth), depth_m)
        if pose is not None and depth.T_cam_depth is not None:
            pose = pose @ pose_inverse(depth.T_cam_depth.double())
        with self._lock:
            self._frames, self._reasons, self._resumed = self._odometry.counters.frames, dict(self._odometry.counters.gaps), self._odometry.counters.resumed
            self._wall.append(time.perf_counter() - wall)
            self._cpu.append(time.thread_time() - cpu)
            del self._wall[:-_MAX_SAMPLES], self._cpu[:-_MAX_SAMPLES]
        if pose is None:
            return
        self.publish(OdometryEvent(event.stamp, pose.to(torch.float64), frame.stamp_ns))
        now = self.clock()
        with self._lock:
            self.published += 1
            self._latency.append(now - handed_over)
            self._published_at.append(now)
            del self._latency[:-_MAX_SAMPLES], self._published_at[:-_MAX_SAMPLES]

    def counters(self, timings: bool = True) -> dict[str, int]:
        """Frames, poses, gaps (``odometry_gaps_<reason>``), and with ``timings`` the time per frame, latency
        and rate (see the module; their percentiles cost a sort of every frame's)."""
        with self._lock:
            wall, cpu, latency, stamps = (list(self._wall), list(self._cpu), list(self._latency), list(self._published_at)) if timings else ([], [], [], [])
            dropped, published, frames, reasons, resumed = self.dropped, self.published, self._frames, dict(self._reasons), self._resumed
        if dropped:
            reasons["dropped"] = dropped
        counts = {
            "odometry_frames": frames + dropped,
            "odometry_poses": published,
            "odometry_gaps": sum(reasons.values()),
            **{f"odometry_gaps_{reason}": n for reason, n in reasons.items()},
            "odometry_resumed": resumed,
        }
        counts |= _percentiles(wall, "odometry_wall") | _percentiles(cpu, "odometry_cpu") | _percentiles(latency, "odometry_latency")
        if len(stamps) >= 2 and stamps[-1] > stamps[0]:
            counts["odometry_rate_mhz"] = int(round(1000.0 * (len(stamps) - 1) / (stamps[-1] - stamps[0])))
        return counts

    def close(self, timeout: float = 10.0) -> None:
        """Finish the frames handed over (up to ``timeout`` s), then stop the thread.

        Raises:
            RuntimeError: the stage's thread failed (its error chained).
        """
        deadline = time.monotonic() + timeout
        while self._thread.is_alive():
            try:
                self._queue.put(_STOP, timeout=0.1)
                break
            except queue.Full:
                if time.monotonic() > deadline:
                    logger.warning("online odometry still busy after %.0f s; left to end with the process", timeout)
                    return
        self._thread.join(max(0.0, deadline - time.monotonic()))
        logger.info("online odometry: %s", self.counters())
        if self._failure is not None:
            raise RuntimeError("the online odometry failed") from self._failure

    def __enter__(self) -> OdometryStage:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
