"""ROS 2 sensor topics (odometry, camera info, images) -> locnerf's wire messages.

Used by the filter's bridge (the filter reads the topics itself) and by the ingest's ``ros2``
source (which republishes them on ``sensors/odom`` and ``sensors/image``). The subscription
callbacks only enqueue; the translation runs on the consumer's thread and raises
:class:`DecodeError` with a ``ros2_*`` kind, for the consumer's bad-message counters.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from locnerf.messages.codec import DecodeError, encode, encode_image
from locnerf.messages.schemas import ImageHeader, Odometry
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2 import convert
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import check_key
from locnerf.ros2.types import deserialize
from services.ros2.config import Ros2Config
from services.ros2.node import Ros2Node

ODOMETRY = "nav_msgs/msg/Odometry"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

# (payload, attachment) of a received ROS 2 sample
Received = tuple[bytes, bytes | None]
# arrive(urgent, kind, key, received): queue a message for the consumer's thread
Arrive = Callable[[bool, str, str, Received], None]


def open_sample(key: str, received: Received, domain_id: int, fq_name: str, ros_type: str) -> object:
    """Check a sample's key and attachment, and deserialise it as ``ros_type``.

    Raises:
        DecodeError: ``ros2_key``, ``ros2_type_name``, ``ros2_type_hash``, ``ros2_attachment`` or ``ros2_cdr``.
    """
    payload, attachment = received
    check_key(key, domain_id, fq_name, ros_type)
    Attachment.decode(attachment)
    return deserialize(payload, ros_type)


class Ros2Sensors:
    """Subscribes to the sensor topics of ``config`` on ``node`` and translates their samples.

    Args:
        node: the ROS 2 node the subscriptions belong to.
        config: topic names, domain, frames, image transport.
    """

    def __init__(self, node: Ros2Node, config: Ros2Config) -> None:
        self.node = node
        self.config = config
        self.names: dict[str, str] = {}
        self.image_type = IMAGE if config.image_transport == "raw" else COMPRESSED_IMAGE
        self._camera: tuple[PinholeIntrinsics, np.ndarray, np.ndarray] | None = None  # newest CameraInfo: intrinsics, K (3, 3), distortion

    def subscribe(self, arrive: Arrive, image_arrived: Callable[[str, Received], None]) -> None:
        """Odometry (urgent lane), camera info (normal lane) and images (``image_arrived``, newest only)."""
        for kind, topic, ros_type, urgent in (
            ("odometry", self.config.odometry_topic, ODOMETRY, True),
            ("camera_info", self.config.camera_info_topic, CAMERA_INFO, False),
        ):
            self.names[kind] = self.node.subscription(
                topic, ros_type, lambda key, payload, attachment, kind=kind, urgent=urgent: arrive(urgent, kind, key, (payload, attachment))
            )
        self.names["image"] = self.node.subscription(
            self.config.image_topic, self.image_type, lambda key, payload, attachment: image_arrived(key, (payload, attachment))
        )

    def open(self, kind: str, ros_type: str, key: str, received: Received) -> object:
        """:func:`open_sample` for the topic of ``kind`` (odometry, camera_info, image)."""
        return open_sample(key, received, self.config.domain_id, self.names[kind], ros_type)

    def odometry(self, key: str, received: Received) -> bytes:
        """nav_msgs/Odometry of base_frame_id in odom_frame_id -> a locnerf Odometry payload."""
        message = self.open("odometry", ODOMETRY, key, received)
        frames = (message.header.frame_id.lstrip("/"), message.child_frame_id.lstrip("/"))
        if frames != (self.config.odom_frame_id, self.config.base_frame_id):
            raise DecodeError(
                "ros2_frame", f"odometry of {frames[1]!r} in {frames[0]!r}, expected {self.config.base_frame_id!r} in {self.config.odom_frame_id!r}"
            )
        pose = convert.pose_from_message(message.pose.pose)
        return encode(Odometry(stamp=convert.seconds(message.header.stamp), frame_id=self.config.odom_frame_id, T_odom_body=pose.tolist()))

    def camera_info(self, key: str, received: Received) -> None:
        """Keep the intrinsics and distortion for the following images (nothing to hand on)."""
        self._camera = convert.intrinsics_from_camera_info(self.open("camera_info", CAMERA_INFO, key, received))

    def image(self, key: str, received: Received) -> bytes:
        """sensor_msgs/Image or CompressedImage -> a locnerf image frame (undistorted, RGB)."""
        message = self.open("image", self.image_type, key, received)
        if self._camera is None:
            raise DecodeError("ros2_no_camera_info", f"image before any CameraInfo on {self.names['camera_info']}")
        intrinsics, k, distortion = self._camera
        pixels = convert.pixels_from_image(message) if self.image_type == IMAGE else convert.pixels_from_compressed(message)
        if pixels.shape[:2] != (intrinsics.height, intrinsics.width):
            raise DecodeError("ros2_image_size", f"image {pixels.shape[1]}×{pixels.shape[0]}, camera info {intrinsics.width}×{intrinsics.height}")
        pixels = convert.undistort(pixels, k, distortion)
        header = ImageHeader(
            stamp=convert.seconds(message.header.stamp),
            frame_id=message.header.frame_id,
            encoding="rgb8",
            width=intrinsics.width,
            height=intrinsics.height,
            intrinsics=intrinsics,
        )
        return encode_image(header, pixels)
