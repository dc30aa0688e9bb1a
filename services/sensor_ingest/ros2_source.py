"""The ``ros2`` source: a ROS 2 robot's odometry and camera topics (rmw_zenoh, docs/ROS2.md)
republished on locnerf's ``sensors/odom`` and ``sensors/image``, for a filter that does not speak
ROS 2 itself (a filter with ``[ros2] sensors = true`` reads the topics directly instead).

Callbacks only enqueue: odometry, camera infos and depth-image wake-ups into a FIFO, colour images
into a one-slot buffer (newest only), depth images into the translator's small buffer. One thread
translates and publishes: the queued odometry, camera infos and depth images first, then the
newest colour image, which waits for the depth image of its stamp when a depth topic is set
(:class:`~services.ros2.depth_pairing.DepthPairing`) and leaves as one RGB-D frame. With an
``odometry`` stage (a camera without VIO), each RGB-D frame is also handed to it, which publishes the
odometry computed from it (services/sensor_ingest/odometry_stage.py).
Bad samples are counted by kind and logged once per kind (:class:`BadMessages`), then dropped.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import torch

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode_rgbd
from locnerf.sim.events import DepthFrame, ImageEvent, RgbdFrameEvent
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.ros2.sensors import Received, Ros2Sensors
from locnerf_services.runtime import BadMessages
from locnerf_services.sensor_ingest.odometry_stage import OdometryStage
from locnerf_services.transport import Bus, Inbox, LatestSlot

logger = logging.getLogger(__name__)

_TOPICS = {"odometry": keys.ODOMETRY, "image": keys.IMAGE}
_DEPTH_ARRIVED = ("depth", "", (b"", None))  # a wake-up: the sample waits in Ros2Sensors.depth_samples


class Ros2Ingest:
    """A ROS 2 node ``<node_name>_ingest`` subscribed to the sensor topics of ``config``.

    Args:
        bus: the Zenoh session (the same one carries ROS 2 and locnerf's keys).
        robot_id: locnerf key prefix of the republished messages.
        config: topic names, domain, namespace, frames and depth pairing (the filter's output fields are unused).
        bad: where bad samples are counted (the ingest's status reports it); a new one when None.
        clock: monotonic wall-clock seconds (the wait of a colour image for its depth image).
        odometry: the online odometry fed with every RGB-D frame (None: the robot publishes odometry).
    """

    def __init__(
        self,
        bus: Bus,
        robot_id: str,
        config: Ros2Config,
        bad: BadMessages | None = None,
        clock: Callable[[], float] = time.monotonic,
        odometry: OdometryStage | None = None,
    ) -> None:
        self.odometry = odometry
        self.bus = bus
        self.robot_id = robot_id
        self.node = Ros2Node(bus, config.domain_id, f"{config.node_name}_ingest", config.namespace)
        self.sensors = Ros2Sensors(self.node, config, clock)
        self.inbox: Inbox[tuple[str, str, Received]] = Inbox(capacity=256)
        self.images: LatestSlot[tuple[str, Received]] = LatestSlot()
        self.bad = BadMessages("sensor_ingest") if bad is None else bad
        self.sent = 0
        self.sensors.subscribe(
            lambda _urgent, kind, key, received: self.inbox.put((kind, key, received)),
            lambda key, received: self.images.put((key, received)),
            lambda: self.inbox.put(_DEPTH_ARRIVED),
        )

    def step(self, timeout: float) -> None:
        """Republish what arrived, waiting up to ``timeout`` seconds (less while a colour image waits
        for its depth) for odometry, a camera info or a depth image: every queued one first (so an
        image finds the camera info sent before it, and its depth image if it has come), then the
        newest colour image once its pairing is settled."""
        waiting = self.sensors.pairing.time_left()
        item = self.inbox.get(timeout if waiting is None else min(timeout, waiting))
        while item is not None:
            kind, key, received = item
            if kind == "depth":
                self._translate(self.sensors.take_depth)
            else:
                self._republish(kind, key, received)
            item = self.inbox.get(0.0)
        image = self.images.take()
        if image is not None:
            self._translate(self.sensors.image, *image)
        frame = self._translate(self.sensors.paired_image)
        if frame is not None:
            self._publish("image", frame)
            if self.odometry is not None:
                self._odometry_frame(frame)

    def _odometry_frame(self, frame: bytes) -> None:
        """Hand an RGB-D frame (as published) to the online odometry; a colour-only frame has nothing for it."""
        header, pixels, millimetres = decode_rgbd(frame)
        if header.depth is None or millimetres is None:
            return
        offset = None if header.depth.T_cam_depth is None else torch.tensor(header.depth.T_cam_depth, dtype=torch.float64)
        image = ImageEvent(header.stamp, pixels, header.intrinsics, DepthFrame(millimetres, header.depth.intrinsics, offset), header.stamp_ns)
        self.odometry.submit(RgbdFrameEvent(header.stamp, image))

    def counters(self, timings: bool = False) -> dict[str, int]:
        """What the ingest's status reports besides its bad messages (with ``timings``, the online odometry's times too)."""
        counts = {"events_sent": self.sent, "images_replaced": self.images.replaced + self.sensors.pairing.replaced}
        if self.odometry is not None:
            counts |= self.odometry.counters(timings)
        if self.sensors.config.depth_topic:
            counts["images_without_depth"] = self.sensors.images_without_depth
        return counts

    def _translate(self, translate: Callable[..., bytes | None], *args: object) -> bytes | None:
        """``translate(*args)``; a bad sample is counted and gives None."""
        try:
            return translate(*args)
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
            return None

    def _republish(self, kind: str, key: str, received: Received) -> None:
        payload = self._translate(getattr(self.sensors, kind), key, received)
        if payload is not None and kind in _TOPICS:
            self._publish(kind, payload)

    def _publish(self, kind: str, payload: bytes) -> None:
        self.bus.publish(keys.key(self.robot_id, _TOPICS[kind]), payload)
        self.sent += 1

    def close(self) -> None:
        """Undeclare the node (its tokens vanish from the ROS 2 graph)."""
        self.node.close()
        logger.info("ros2 ingest: %d messages republished, %d bad (%s), counters %s", self.sent, self.bad.total, dict(self.bad.counts), self.counters())
