"""Record ROS 2 topics from the Zenoh session (rmw_zenoh's layout) into an MCAP rosbag2, as ``ros2 bag record`` does.

By default the topics of a :class:`Ros2Config`: what the filter publishes (``amcl_pose``,
``particle_cloud``, ``/tf``) and the sensor topics it reads (odometry, images, camera infos, depth).
Each sample's CDR is written as received, at its receive time (wall clock, nanoseconds since the
epoch, as rosbag2's recorder stamps it); the message definitions come from locnerf's type store.
A sample on a topic's key with another type name or hash, or without a valid attachment, is
counted (``ros2_type_name``, ``ros2_type_hash``, ``ros2_key``, ``ros2_attachment``) and not recorded.

Transport callbacks only enqueue; :meth:`Ros2Recorder.step` writes on the caller's thread.
"""

from __future__ import annotations

import logging
import time

from locnerf.bags.writer import BagWriter
from locnerf.messages.codec import DecodeError
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import check_key
from locnerf.ros2.types import CAMERA_INFO, IMAGE, NAV2_PARTICLE_CLOUD, ODOMETRY, TF_MESSAGE
from locnerf.ros2.types import POSE_WITH_COVARIANCE_STAMPED as POSE_WITH_COVARIANCE
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.runtime import BadMessages
from locnerf_services.transport import Bus, Inbox

logger = logging.getLogger(__name__)

INBOX_CAPACITY = 1024
"""Samples waiting to be written (the oldest are dropped, and counted, beyond it)."""


def default_topics(config: Ros2Config, inputs: bool = True) -> list[tuple[str, str]]:
    """(topic, ROS type) of the filter's outputs and, with ``inputs``, of its sensor topics."""
    topics = [(config.pose_topic, POSE_WITH_COVARIANCE), (config.particles_topic, NAV2_PARTICLE_CLOUD), (config.tf_topic, TF_MESSAGE)]
    if inputs:
        image_type = IMAGE if config.image_transport == "raw" else "sensor_msgs/msg/CompressedImage"
        topics += [(config.odometry_topic, ODOMETRY), (config.image_topic, image_type), (config.camera_info_topic, CAMERA_INFO)]
        if config.depth_topic:
            topics.append((config.depth_topic, IMAGE))
        if config.depth_camera_info_topic:
            topics.append((config.depth_camera_info_topic, CAMERA_INFO))
    return topics


class Ros2Recorder:
    """A ROS 2 node ``locnerf_recorder`` subscribed to ``topics``, writing their samples to ``bag``.

    Args:
        bus: the Zenoh session.
        bag: the bag being written.
        topics: (name, ROS type) pairs; names are resolved in ``namespace``.
        domain_id, namespace: the ROS 2 graph's.
    """

    def __init__(self, bus: Bus, bag: BagWriter, topics: list[tuple[str, str]], domain_id: int = 0, namespace: str = "") -> None:
        self.bag = bag
        self.domain_id = domain_id
        self.node = Ros2Node(bus, domain_id, "locnerf_recorder", namespace)
        self.inbox: Inbox[tuple[str, str, str, bytes, bytes | None, int]] = Inbox(capacity=INBOX_CAPACITY)
        self.bad = BadMessages("recorder")
        for name, ros_type in topics:
            fq_name = self.node.resolve(name)
            self.node.subscription(
                name,
                ros_type,
                lambda key, payload, attachment, fq_name=fq_name, ros_type=ros_type: self.inbox.put(
                    (fq_name, ros_type, key, payload, attachment, time.time_ns())
                ),
            )

    def step(self, timeout: float) -> int:
        """Write what arrived, waiting up to ``timeout`` seconds for the first sample; returns the samples written."""
        written = 0
        item = self.inbox.get(timeout)
        while item is not None:
            fq_name, ros_type, key, payload, attachment, received = item
            try:
                check_key(key, self.domain_id, fq_name, ros_type)
                Attachment.decode(attachment)
            except DecodeError as error:
                self.bad.record(error.kind, f"{fq_name}: {error.reason}")
            else:
                self.bag.write_cdr(fq_name, ros_type, received, payload)
                written += 1
            item = self.inbox.get(0.0)
        return written

    def close(self) -> None:
        """Undeclare the node; log what was recorded."""
        self.node.close()
        logger.info("recorder: %s written, %d bad (%s), %d dropped (inbox full)", self.bag.counts, self.bad.total, dict(self.bad.counts), self.inbox.dropped)
