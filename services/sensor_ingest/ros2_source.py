"""The ``ros2`` source: a ROS 2 robot's odometry and camera topics (rmw_zenoh, docs/ROS2.md)
republished on locnerf's ``sensors/odom`` and ``sensors/image``, for a filter that does not speak
ROS 2 itself (a filter with ``[ros2] sensors = true`` reads the topics directly instead).

Callbacks only enqueue: odometry and camera infos into a FIFO, images into a one-slot buffer
(newest only). One thread translates and publishes, the queued odometry and camera infos before
the image.
Bad samples are counted by kind and logged once per kind (:class:`BadMessages`), then dropped.
"""

from __future__ import annotations

import logging

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError
from services.ros2.config import Ros2Config
from services.ros2.node import Ros2Node
from services.ros2.sensors import Received, Ros2Sensors
from services.runtime import BadMessages
from services.transport import Bus, Inbox, LatestSlot

logger = logging.getLogger(__name__)

_TOPICS = {"odometry": keys.ODOMETRY, "image": keys.IMAGE}


class Ros2Ingest:
    """A ROS 2 node ``<node_name>_ingest`` subscribed to the sensor topics of ``config``.

    Args:
        bus: the Zenoh session (the same one carries ROS 2 and locnerf's keys).
        robot_id: locnerf key prefix of the republished messages.
        config: topic names, domain, namespace and frames (the filter's output fields are unused).
        bad: where bad samples are counted (the ingest's status reports it); a new one when None.
    """

    def __init__(self, bus: Bus, robot_id: str, config: Ros2Config, bad: BadMessages | None = None) -> None:
        self.bus = bus
        self.robot_id = robot_id
        self.node = Ros2Node(bus, config.domain_id, f"{config.node_name}_ingest", config.namespace)
        self.sensors = Ros2Sensors(self.node, config)
        self.inbox: Inbox[tuple[str, str, Received]] = Inbox(capacity=256)
        self.images: LatestSlot[tuple[str, Received]] = LatestSlot()
        self.bad = BadMessages("sensor_ingest") if bad is None else bad
        self.sent = 0
        self.sensors.subscribe(
            lambda _urgent, kind, key, received: self.inbox.put((kind, key, received)), lambda key, received: self.images.put((key, received))
        )

    def step(self, timeout: float) -> None:
        """Republish what arrived, waiting up to ``timeout`` seconds for odometry or a camera info:
        every queued odometry and camera info first (so an image finds the camera info sent before
        it), then the newest image."""
        item = self.inbox.get(timeout)
        while item is not None:
            self._republish(*item)
            item = self.inbox.get(0.0)
        image = self.images.take()
        if image is not None:
            self._republish("image", *image)

    def _republish(self, kind: str, key: str, received: Received) -> None:
        try:
            payload = getattr(self.sensors, kind)(key, received)
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
            return
        if kind in _TOPICS:
            self.bus.publish(keys.key(self.robot_id, _TOPICS[kind]), payload)
            self.sent += 1

    def close(self) -> None:
        """Undeclare the node (its tokens vanish from the ROS 2 graph)."""
        self.node.close()
        logger.info("ros2 ingest: %d messages republished, %d bad (%s)", self.sent, self.bad.total, dict(self.bad.counts))
