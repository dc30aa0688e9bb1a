"""ROS 2 sensor topics (odometry, camera infos, colour and depth images) -> locnerf's wire messages.

Used by the filter's bridge (the filter reads the topics itself) and by the ingest's ``ros2``
source (which republishes them on ``sensors/odom`` and ``sensors/image``). The subscription
callbacks only enqueue; the translation runs on the consumer's thread and raises
:class:`DecodeError` with a ``ros2_*`` kind, for the consumer's bad-message counters.

With a depth topic, each colour image waits for the depth image of its stamp
(:class:`~services.ros2.depth_pairing.DepthPairing`) and the pair leaves as one RGB-D frame: the
consumer hands colour images to :meth:`Ros2Sensors.image` as they come, calls
:meth:`Ros2Sensors.take_depth` for each depth image announced (the samples wait here, in a small
buffer), and takes the frames from :meth:`Ros2Sensors.paired_image` (again after each depth image:
it may complete a waiting pair). Depth images are translated on arrival (so a bad one is counted
as it comes, and never holds back the colour image), colour images when they leave.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from locnerf.geometry.frames import camera_extrinsic_opencv_to_opengl
from locnerf.messages.codec import DecodeError, encode, encode_image
from locnerf.messages.schemas import DepthHeader, ImageHeader, Matrix, Odometry
from locnerf.ros2 import convert
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.camera_info import CameraSlot, undistorted_colour, undistorted_depth
from locnerf.ros2.naming import check_key
from locnerf.ros2.types import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, ODOMETRY, deserialize
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.depth_pairing import DepthPairing
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.transport import Inbox

# (payload, attachment) of a received ROS 2 sample
Received = tuple[bytes, bytes | None]
# arrive(urgent, kind, key, received): queue a message for the consumer's thread
Arrive = Callable[[bool, str, str, Received], None]
# image_arrived(key, received): keep the newest colour image for the consumer's thread
ImageArrived = Callable[[str, Received], None]

DEPTH_SAMPLES_WAITING = 8
"""Depth samples kept untranslated until the consumer takes them (the oldest dropped): about 1 MB
each, they wait here rather than in the consumer's message queue, which only gets a wake-up."""


@dataclass(frozen=True)
class DepthImage:
    """A translated depth image: its header (camera, offset) and the (Hd, Wd) uint16 millimetres, undistorted."""

    header: DepthHeader
    millimetres: np.ndarray


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
        config: topic names, domain, frames, image transport, depth pairing.
        clock: monotonic wall-clock seconds (the wait for a depth image).
    """

    def __init__(self, node: Ros2Node, config: Ros2Config, clock: Callable[[], float] = time.monotonic) -> None:
        self.node = node
        self.config = config
        self.names: dict[str, str] = {}
        self.image_type = IMAGE if config.image_transport == "raw" else COMPRESSED_IMAGE
        self._camera = CameraSlot(config.images_rectified)  # newest colour CameraInfo
        self._depth_camera = CameraSlot(config.depth_images_rectified)  # newest depth CameraInfo (unregistered depth)
        self.T_cam_depth: Matrix | None = None if config.T_colour_depth is None else _opengl_offset(config.T_colour_depth)
        # Without a depth topic nothing is waited for: each colour image leaves at once.
        wait = config.depth_max_wait if config.depth_topic else 0.0
        self.pairing: DepthPairing[object, DepthImage] = DepthPairing(config.depth_pairing_tolerance, wait, clock)
        self.depth_samples: Inbox[tuple[str, Received]] = Inbox(capacity=DEPTH_SAMPLES_WAITING)

    @property
    def images_without_depth(self) -> int:
        """Colour images that left without a depth image although a depth topic is configured."""
        return self.pairing.without_depth if self.config.depth_topic else 0

    def subscribe(self, arrive: Arrive, image_arrived: ImageArrived, depth_arrived: Callable[[], None]) -> None:
        """Odometry (urgent lane), camera infos (normal lane), colour images (``image_arrived``, newest
        only) and, with a depth topic, depth images: kept in :attr:`depth_samples`, each announced by
        ``depth_arrived()``, after which the consumer calls :meth:`take_depth`."""
        queued = [("odometry", self.config.odometry_topic, ODOMETRY, True), ("camera_info", self.config.camera_info_topic, CAMERA_INFO, False)]
        if self.config.depth_topic and self.config.depth_camera_info_topic:
            queued.append(("depth_camera_info", self.config.depth_camera_info_topic, CAMERA_INFO, False))
        for kind, topic, ros_type, urgent in queued:
            if not topic:  # odometry_topic '': a camera without VIO (the ingest computes odometry from its RGB-D frames)
                continue
            self.names[kind] = self.node.subscription(
                topic, ros_type, lambda key, payload, attachment, kind=kind, urgent=urgent: arrive(urgent, kind, key, (payload, attachment))
            )
        self.names["image"] = self.node.subscription(
            self.config.image_topic, self.image_type, lambda key, payload, attachment: image_arrived(key, (payload, attachment))
        )
        if self.config.depth_topic:
            self.names["depth"] = self.node.subscription(
                self.config.depth_topic, IMAGE, lambda key, payload, attachment: self._depth_arrived(key, (payload, attachment), depth_arrived)
            )

    def _depth_arrived(self, key: str, received: Received, wake: Callable[[], None]) -> None:
        """Transport thread: keep the sample, then wake the consumer."""
        self.depth_samples.put((key, received))
        wake()

    def open(self, kind: str, ros_type: str, key: str, received: Received) -> object:
        """:func:`open_sample` for the topic of ``kind`` (odometry, camera_info, depth_camera_info, image, depth)."""
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
        return encode(Odometry(stamp_ns=convert.nanoseconds(message.header.stamp), frame_id=self.config.odom_frame_id, T_odom_body=pose.tolist()))

    def camera_info(self, key: str, received: Received) -> None:
        """Keep the camera (intrinsics, undistortion) for the following images (nothing to hand on).

        Raises:
            DecodeError: as :func:`open_sample`; ``ros2_camera_info``, ``ros2_camera_info_unsupported``
                (:mod:`locnerf.ros2.camera_info`): the previous camera stays.
        """
        self._camera.update(self.open("camera_info", CAMERA_INFO, key, received))

    def depth_camera_info(self, key: str, received: Received) -> None:
        """Keep the depth camera for the following depth images (as :meth:`camera_info`)."""
        self._depth_camera.update(self.open("depth_camera_info", CAMERA_INFO, key, received))

    def image(self, key: str, received: Received) -> None:
        """A sensor_msgs/Image or CompressedImage: it waits for its depth image (:meth:`paired_image`)."""
        message = self.open("image", self.image_type, key, received)
        self.pairing.add_colour(convert.seconds(message.header.stamp), message)

    def take_depth(self) -> None:
        """Translate the oldest waiting depth sample (:meth:`depth`); nothing when none waits.

        Raises:
            DecodeError: as :meth:`depth`.
        """
        sample = self.depth_samples.get(0.0)
        if sample is not None:
            self.depth(*sample)

    def depth(self, key: str, received: Received) -> None:
        """A depth sensor_msgs/Image, translated (millimetres, undistorted, its camera) for the pairing.

        Raises:
            DecodeError: as :func:`open_sample`; ``ros2_no_camera_info`` before the camera info that
                describes it, ``ros2_depth_encoding``, and ``ros2_depth_size`` when it does not have
                that camera's size.
        """
        message = self.open("depth", IMAGE, key, received)
        registered = not self.config.depth_camera_info_topic
        camera = (self._camera if registered else self._depth_camera).camera
        millimetres = undistorted_depth(message, camera, self.names["camera_info" if registered else "depth_camera_info"], registered)
        intrinsics = camera.intrinsics
        header = DepthHeader(width=intrinsics.width, height=intrinsics.height, intrinsics=intrinsics, T_cam_depth=self.T_cam_depth)
        self.pairing.add_depth(convert.seconds(message.header.stamp), DepthImage(header, millimetres))

    def paired_image(self) -> bytes | None:
        """The waiting colour image as a locnerf image frame (undistorted, RGB, with its depth image when
        one was paired) once its pairing is settled; None while it waits or when none waits.

        Raises:
            DecodeError: ``ros2_no_camera_info``, ``ros2_encoding``, ``ros2_image_size`` for the colour image (dropped).
        """
        released = self.pairing.release()
        if released is None:
            return None
        message, depth = released
        camera = self._camera.camera
        pixels = undistorted_colour(message, camera, self.image_type == COMPRESSED_IMAGE, self.names["camera_info"])
        intrinsics = camera.intrinsics
        header = ImageHeader(
            stamp_ns=convert.nanoseconds(message.header.stamp),
            frame_id=message.header.frame_id,
            encoding="rgb8",
            width=intrinsics.width,
            height=intrinsics.height,
            intrinsics=intrinsics,
            depth=None if depth is None else depth.header,
        )
        return encode_image(header, pixels, None if depth is None else depth.millimetres)


def _opengl_offset(T_colour_depth_optical: list[list[float]]) -> Matrix:
    """The configured ROS optical-frame extrinsic (OpenCV axes) as DepthHeader.T_cam_depth (OpenGL axes),
    its last row exactly 0 0 0 1 (the configuration's check allows 1e-3, the wire's 1e-9)."""
    offset = camera_extrinsic_opencv_to_opengl(torch.tensor(T_colour_depth_optical, dtype=torch.float64))
    offset[3] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    return offset.tolist()
