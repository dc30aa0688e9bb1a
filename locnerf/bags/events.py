"""A rosbag2's odometry, camera and ground-truth topics as locnerf's sensor events, in bag order.

Messages are translated with the ROS 2 node's conversions (:mod:`locnerf.ros2.convert`,
:mod:`locnerf.ros2.camera_info`): odometry -> :class:`OdometryEvent` (``T_odom_body``), colour
images undistorted onto their CameraInfo's pinhole camera -> :class:`ImageEvent`, each with the
depth image of its stamp when the bag has a depth topic (nearest within ``DEPTH_TOLERANCE_NS``),
ground truth (``T_world_body · T_body_cam``) -> :class:`GroundTruthEvent`. Events carry the
messages' header stamps, exactly (``stamp_ns``) and as seconds.

A bad message is counted by kind, reported through ``record(kind, reason)`` (the reason names the
topic and what was expected) and skipped; the replay goes on. Kinds: those of the ROS 2 node
(``ros2_cdr``, ``ros2_encoding``, ``ros2_image_size``, ``ros2_depth_encoding``, ``ros2_depth_size``,
``ros2_camera_info``, ``ros2_no_camera_info``, ``ros2_invalid``) and ``bag_stamp_backwards`` (a
message stamped before the previous one of its topic).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
from collections.abc import Callable, Iterator
from pathlib import Path

import torch

from locnerf.bags.reader import open_bag, raw_messages, topic_types
from locnerf.bags.topics import BagTopics, ChosenTopics, choose_topics
from locnerf.geometry.frames import camera_extrinsic_opencv_to_opengl
from locnerf.geometry.se3 import pose_inverse
from locnerf.messages.codec import DecodeError
from locnerf.messages.stamps import seconds_from_nanoseconds
from locnerf.ros2 import convert
from locnerf.ros2.camera_info import CameraSlot, undistorted_colour, undistorted_depth
from locnerf.ros2.types import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, ODOMETRY, POSE_STAMPED, TF_MESSAGE, deserialize, message_class
from locnerf.sim.events import DepthFrame, GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent

logger = logging.getLogger(__name__)

DEPTH_TOLERANCE_NS = 20_000_000
"""A colour image and a depth image are one RGB-D frame when their stamps are at most 20 ms apart (the ROS 2 node's default)."""
DEPTH_WAIT_NS = 100_000_000
"""Bag time a colour image waits for its depth image before it goes alone."""
TF_STATIC = "/tf_static"

Record = Callable[[str, str], None]
"""``record(kind, reason)``: count one bad message."""


class BagProblems:
    """Counts bad messages by kind; logs the first of each kind (the reason names the topic)."""

    def __init__(self, bag: str | Path) -> None:
        self.bag = str(bag)
        self.counts: collections.Counter[str] = collections.Counter()

    def record(self, kind: str, reason: str) -> None:
        if self.counts[kind] == 0:
            logger.warning("bag %s: skipping a bad message (%s): %s (further ones are only counted)", self.bag, kind, reason)
        self.counts[kind] += 1


class BagTranslator:
    """Translates one bag message at a time (:meth:`take`) into the events it completes.

    Args:
        topics: the chosen topics.
        T_body_cam: (4, 4) float64 camera (OpenGL axes) in the body: ground truth of the body becomes the camera's.
        T_colour_depth: (4, 4) float64 pose of the depth optical frame in the colour optical frame
            (OpenCV axes, metres) for an unregistered depth camera; None: the same pose.
        record: counts a bad message.
    """

    def __init__(self, topics: ChosenTopics, T_body_cam: torch.Tensor, T_colour_depth: torch.Tensor | None, record: Record) -> None:
        self.topics = topics
        self.T_body_cam = T_body_cam
        self.T_cam_depth = None if T_colour_depth is None else camera_extrinsic_opencv_to_opengl(T_colour_depth)
        self.record = record
        self.camera = CameraSlot(rectified=False)
        self.depth_camera = CameraSlot(rectified=False)
        self.last_stamp: dict[str, int] = {}
        self.waiting: tuple[int, ImageEvent] | None = None  # a colour image waiting for its depth image
        self.depths: collections.deque[tuple[int, DepthFrame]] = collections.deque(maxlen=8)

    def take(self, topic: str, bag_time: int, data: bytes) -> list[SensorEvent]:
        """The events that message ``data`` of ``topic`` (at bag time ``bag_time`` ns) completes; a bad one is recorded and gives none."""
        events = self._expire(bag_time)
        try:
            events += self._translate(topic, data)
        except DecodeError as error:
            self.record(error.kind, f"{topic}: {error.reason}")
        return events

    def finish(self) -> list[SensorEvent]:
        """The colour image still waiting for its depth image, alone."""
        return self._expire(None)

    def _in_order(self, topic: str, stamp_ns: int) -> None:
        previous = self.last_stamp.get(topic)
        if previous is not None and stamp_ns < previous:
            raise DecodeError("bag_stamp_backwards", f"stamp {stamp_ns} ns after {previous} ns: expected the stamps of a topic not to decrease")
        self.last_stamp[topic] = stamp_ns

    def _translate(self, topic: str, data: bytes) -> list[SensorEvent]:
        chosen = self.topics
        if topic == chosen.camera_info:
            self.camera.update(deserialize(data, CAMERA_INFO))
            return []
        if topic == chosen.depth_camera_info:
            self.depth_camera.update(deserialize(data, CAMERA_INFO))
            return []
        if topic == chosen.odometry:
            message = deserialize(data, ODOMETRY)
            stamp = convert.nanoseconds(message.header.stamp)
            pose = convert.pose_from_message(message.pose.pose)
            self._in_order(topic, stamp)
            return [OdometryEvent(seconds_from_nanoseconds(stamp), pose, stamp)]
        if topic == chosen.image:
            return self._colour(topic, data)
        if topic == chosen.depth:
            return self._depth(topic, data)
        if topic == chosen.ground_truth:
            return self._truth(topic, data)
        return []

    def _colour(self, topic: str, data: bytes) -> list[SensorEvent]:
        message = deserialize(data, self.topics.image_type)
        stamp = convert.nanoseconds(message.header.stamp)
        pixels = undistorted_colour(message, self.camera.camera, self.topics.image_type == COMPRESSED_IMAGE, self.topics.camera_info)
        self._in_order(topic, stamp)
        event = ImageEvent(seconds_from_nanoseconds(stamp), pixels, self.camera.camera.intrinsics, stamp_ns=stamp)
        if self.topics.depth is None:
            return [event]
        events = self._expire(None)  # a newer colour image: the waiting one goes alone
        depth = self._nearest_depth(stamp)
        if depth is not None:
            return events + [dataclasses.replace(event, depth=depth)]
        self.waiting = (stamp, event)
        return events

    def _depth(self, topic: str, data: bytes) -> list[SensorEvent]:
        message = deserialize(data, IMAGE)
        stamp = convert.nanoseconds(message.header.stamp)
        registered = self.topics.depth_camera_info is None
        slot = self.camera if registered else self.depth_camera
        info_topic = self.topics.camera_info if registered else self.topics.depth_camera_info
        millimetres = undistorted_depth(message, slot.camera, info_topic, registered)
        self._in_order(topic, stamp)
        frame = DepthFrame(millimetres, slot.camera.intrinsics, None if registered else self.T_cam_depth)
        self.depths.append((stamp, frame))
        if self.waiting is not None and abs(self.waiting[0] - stamp) <= DEPTH_TOLERANCE_NS:
            _, event = self.waiting
            self.waiting = None
            return [dataclasses.replace(event, depth=frame)]
        return []

    def _nearest_depth(self, stamp: int) -> DepthFrame | None:
        close = [(abs(depth_stamp - stamp), frame) for depth_stamp, frame in self.depths if abs(depth_stamp - stamp) <= DEPTH_TOLERANCE_NS]
        return min(close, key=lambda item: item[0])[1] if close else None

    def _expire(self, bag_time: int | None) -> list[SensorEvent]:
        """The waiting colour image, alone, once ``bag_time`` is past its wait (None: now)."""
        if self.waiting is None or (bag_time is not None and bag_time <= self.waiting[0] + DEPTH_WAIT_NS):
            return []
        _, event = self.waiting
        self.waiting = None
        return [event]

    def _truth(self, topic: str, data: bytes) -> list[SensorEvent]:
        kind = self.topics.ground_truth_type
        message = deserialize(data, kind)
        if kind == TF_MESSAGE:
            found = [t for t in message.transforms if t.child_frame_id.lstrip("/") == self.topics.ground_truth_frame.lstrip("/")]
            if not found:
                return []
            stamped = found[-1]
            stamp, pose = convert.nanoseconds(stamped.header.stamp), _transform_pose(stamped.transform)
        else:
            stamp = convert.nanoseconds(message.header.stamp)
            pose = convert.pose_from_message(message.pose if kind == POSE_STAMPED else message.pose.pose)
        self._in_order(topic, stamp)
        return [GroundTruthEvent(seconds_from_nanoseconds(stamp), pose @ self.T_body_cam, stamp)]


def _transform_pose(transform: object) -> torch.Tensor:
    """geometry_msgs/msg/Transform -> (4, 4) float64 (through :func:`convert.pose_from_message`)."""
    position = message_class("geometry_msgs/msg/Point")(transform.translation.x, transform.translation.y, transform.translation.z)
    return convert.pose_from_message(message_class("geometry_msgs/msg/Pose")(position=position, orientation=transform.rotation))


def static_transform(reader: object, parent: str, child: str) -> torch.Tensor | None:
    """The (4, 4) float64 pose of frame ``child`` in ``parent`` from the bag's /tf_static (either direction); None when absent."""
    if TF_STATIC not in topic_types(reader):
        return None
    for _topic, _time, data in raw_messages(reader, [TF_STATIC]):
        for stamped in deserialize(data, TF_MESSAGE).transforms:
            frames = (stamped.header.frame_id.lstrip("/"), stamped.child_frame_id.lstrip("/"))
            if frames == (parent, child):
                return _transform_pose(stamped.transform)
            if frames == (child, parent):
                return pose_inverse(_transform_pose(stamped.transform))
    return None


def _frame_ids(reader: object, topics: ChosenTopics) -> tuple[str, str] | None:
    """The frame ids of the first colour image and the first depth image."""
    found: dict[str, str] = {}
    for topic, _time, data in raw_messages(reader, [topics.image, topics.depth]):
        if topic not in found:
            try:
                found[topic] = deserialize(data, topics.image_type if topic == topics.image else IMAGE).header.frame_id.lstrip("/")
            except DecodeError:
                continue
        if len(found) == 2:
            return found[topics.image], found[topics.depth]
    return None


def depth_extrinsic(reader: object, topics: ChosenTopics, bag: str) -> torch.Tensor | None:
    """T_colour_depth (OpenCV axes) of an unregistered depth camera from /tf_static; None when registered.
    Without a transform in /tf_static the depth camera is taken at the colour camera's pose (logged)."""
    if topics.depth is None or topics.depth_camera_info is None:
        return None
    frames = _frame_ids(reader, topics)
    offset = None if frames is None else static_transform(reader, *frames)
    if offset is None:
        logger.warning(
            "bag %s: no /tf_static transform between the colour and depth frames %s: the depth camera is taken at the colour camera's pose", bag, frames
        )
    return offset


def bag_events(
    path: str | Path,
    topics: BagTopics | None = None,
    T_body_cam: torch.Tensor | None = None,
    record: Record | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Iterator[SensorEvent]:
    """The bag's sensor events in bag order (see the module).

    Args:
        path: rosbag2 folder or .mcap / .db3 file.
        topics: topic names (defaults: :class:`BagTopics`).
        T_body_cam: (4, 4) camera in the body for the ground truth; None: identity.
        record: counts bad messages (default: :class:`BagProblems`, logged).
        progress: ``progress(done, total)`` after each message read.

    Raises:
        FileNotFoundError, DatasetError: an unreadable bag or unusable topics, before any event.
    """
    body_cam = torch.eye(4, dtype=torch.float64) if T_body_cam is None else T_body_cam.double()
    record = BagProblems(path).record if record is None else record
    with open_bag(path) as reader:
        chosen = choose_topics(topic_types(reader), topics or BagTopics(), str(path))
        translator = BagTranslator(chosen, body_cam, depth_extrinsic(reader, chosen, str(path)), record)
        read = [name for name in (chosen.odometry, chosen.image, chosen.camera_info, chosen.depth, chosen.depth_camera_info, chosen.ground_truth) if name]
        total = sum(connection.msgcount for connection in reader.connections if connection.topic in read)
        logger.info("bag %s: reading %s (%d messages)", path, ", ".join(read), total)
        for done, (topic, bag_time, data) in enumerate(raw_messages(reader, read), start=1):
            yield from translator.take(topic, bag_time, data)
            if progress is not None:
                progress(done, total)
        yield from translator.finish()
