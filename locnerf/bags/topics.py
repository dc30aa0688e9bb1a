"""Which topics of a rosbag2 to read: names with ROS's usual defaults, checked against the bag's types.

A topic is chosen by name (:class:`BagTopics`); when the name of a required topic (odometry, image,
camera info) is not in the bag and exactly one topic of the expected type is, that one is taken (and
logged). Optional topics (depth, ground truth) are read only under their names. The camera info of an image
topic is, as image_transport places it, ``camera_info`` beside the image (``/camera/image_raw`` ->
``/camera/camera_info``). A chosen topic of another type, or a required topic that cannot be found,
is refused with a message naming the topic, its type and what was expected.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import DatasetError
from locnerf.ros2.types import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, ODOMETRY, POSE_STAMPED, TF_MESSAGE

logger = logging.getLogger(__name__)

GROUND_TRUTH_TYPES = (POSE_STAMPED, ODOMETRY, TF_MESSAGE)
OFF = "-"
"""Topic name that turns an optional topic (depth, ground truth) off."""


class BagTopics(BaseModel):
    """Topic names of a bag (leading slash optional)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    odometry: str = Field("/odom", description="nav_msgs/msg/Odometry of the body (base_link) in odom; required.")
    image: str = Field(
        "/camera/image_raw", description="sensor_msgs/msg/Image (rgb8, bgr8, mono8) or CompressedImage (jpeg, png); required. Its camera_info sits beside it."
    )
    camera_info: str = Field("", description="sensor_msgs/msg/CameraInfo of the images; empty: camera_info beside the image topic.")
    depth: str = Field(
        "/camera/depth/image_raw", description=f"Depth sensor_msgs/msg/Image (16UC1/mono16 mm or 32FC1 m); absent from the bag or '{OFF}': colour only."
    )
    depth_camera_info: str = Field(
        "",
        description="CameraInfo of an unregistered depth camera; empty: camera_info beside the depth topic when the bag has it, "
        "else the depth is registered to the colour camera. Its pose in the colour camera comes from /tf_static.",
    )
    ground_truth: str = Field(
        "/ground_truth",
        description=f"Ground truth of the body in the world: PoseStamped, Odometry or /tf (tf2_msgs/msg/TFMessage); absent or '{OFF}': none.",
    )
    ground_truth_frame: str = Field("", description="With ground_truth = '/tf': the child frame of the transform to take (e.g. a motion-capture body).")


@dataclass(frozen=True)
class ChosenTopics:
    """The bag's topics to read (None: absent) and the image topic's type."""

    odometry: str
    image: str
    image_type: str
    camera_info: str
    depth: str | None
    depth_camera_info: str | None
    ground_truth: str | None
    ground_truth_type: str | None
    ground_truth_frame: str


def absolute(name: str) -> str:
    """A topic name with its leading slash (rosbag2 stores absolute names)."""
    return name if name.startswith("/") else "/" + name


def sibling_camera_info(image_topic: str) -> str:
    """``camera_info`` in the image topic's namespace: ``/camera/image_raw/compressed`` -> ``/camera/camera_info``."""
    parts = image_topic.rstrip("/").split("/")
    if parts[-1] == "compressed":
        parts = parts[:-1]
    return "/".join(parts[:-1] + ["camera_info"])


def _described(types: dict[str, str]) -> str:
    return ", ".join(f"{name} ({kind})" for name, kind in sorted(types.items())) or "none"


def _pick(types: dict[str, str], name: str, accepted: tuple[str, ...], role: str, required: bool, bag: str) -> str | None:
    """The topic ``name`` if the bag has it with an accepted type; else the only topic of an accepted type; else None or an error."""
    name = absolute(name)
    if name in types:
        if types[name] not in accepted:
            raise DatasetError(f"bag {bag}: {role} topic {name} is {types[name]}, expected {' or '.join(accepted)}")
        return name
    candidates = sorted(topic for topic, kind in types.items() if kind in accepted)
    if len(candidates) == 1 and required:
        logger.info("bag %s: no %s topic %s, taking %s (%s)", bag, role, name, candidates[0], types[candidates[0]])
        return candidates[0]
    if required:
        found = f"its {' / '.join(accepted)} topics are {candidates}" if candidates else f"it has no {' or '.join(accepted)} topic"
        raise DatasetError(f"bag {bag}: no {role} topic {name} and {found}; choose one by name (topics: {_described(types)})")
    return None


def choose_topics(types: dict[str, str], topics: BagTopics, bag: str) -> ChosenTopics:
    """Resolve ``topics`` against the bag's ``types`` (topic -> ROS type).

    Raises:
        DatasetError: a missing odometry or image topic, a topic of the wrong type, a missing camera
            info, a /tf ground truth without ``ground_truth_frame``.
    """
    odometry = _pick(types, topics.odometry, (ODOMETRY,), "odometry", True, bag)
    image = _pick(types, topics.image, (IMAGE, COMPRESSED_IMAGE), "image", True, bag)
    camera_info = _pick(types, topics.camera_info or sibling_camera_info(image), (CAMERA_INFO,), "camera info", True, bag)
    depth = None if topics.depth == OFF else _pick(types, topics.depth, (IMAGE,), "depth", False, bag)
    depth_camera_info = None
    if depth is not None:
        if topics.depth_camera_info:
            depth_camera_info = _pick(types, topics.depth_camera_info, (CAMERA_INFO,), "depth camera info", True, bag)
        elif types.get(sibling_camera_info(depth)) == CAMERA_INFO and sibling_camera_info(depth) != camera_info:
            depth_camera_info = sibling_camera_info(depth)
    truth = None if topics.ground_truth == OFF else _pick(types, topics.ground_truth, GROUND_TRUTH_TYPES, "ground-truth", False, bag)
    if truth is not None and types[truth] == TF_MESSAGE and not topics.ground_truth_frame:
        raise DatasetError(f"bag {bag}: ground truth from {truth} needs ground_truth_frame, the child frame of the transform to take (e.g. the mocap body)")
    return ChosenTopics(
        odometry=odometry,
        image=image,
        image_type=types[image],
        camera_info=camera_info,
        depth=depth,
        depth_camera_info=depth_camera_info,
        ground_truth=truth,
        ground_truth_type=None if truth is None else types[truth],
        ground_truth_frame=topics.ground_truth_frame,
    )
