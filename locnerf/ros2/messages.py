"""ROS 2 sensor messages built from locnerf's values (rosbags objects): what a VIO, an RGB-D camera
driver and a motion-capture system publish. Stamps are whole nanoseconds; poses (4, 4) float64."""

from __future__ import annotations

import numpy as np
import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2 import convert
from locnerf.ros2.types import CAMERA_INFO, IMAGE, ODOMETRY, POSE_STAMPED, TF_MESSAGE, message_class


def odometry_message(stamp_ns: int, T_odom_base: torch.Tensor, odom_frame: str = "odom", base_frame: str = "base_link") -> object:
    """nav_msgs/Odometry with the pose ``T_odom_base``, zero covariance and zero twist."""
    pose = message_class("geometry_msgs/msg/PoseWithCovariance")(pose=convert.pose_message(T_odom_base), covariance=np.zeros(36))
    vector = message_class("geometry_msgs/msg/Vector3")
    twist = message_class("geometry_msgs/msg/Twist")(linear=vector(0.0, 0.0, 0.0), angular=vector(0.0, 0.0, 0.0))
    return message_class(ODOMETRY)(
        header=convert.header(stamp_ns, odom_frame),
        child_frame_id=base_frame,
        pose=pose,
        twist=message_class("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)),
    )


def pose_stamped_message(stamp_ns: int, pose: torch.Tensor, frame: str = "map") -> object:
    """geometry_msgs/PoseStamped of ``pose`` in ``frame``."""
    return message_class(POSE_STAMPED)(header=convert.header(stamp_ns, frame), pose=convert.pose_message(pose))


def transform_stamped_message(stamp_ns: int, parent: str, child: str, T_parent_child: torch.Tensor) -> object:
    """geometry_msgs/TransformStamped: ``child``'s pose in ``parent``."""
    return message_class("geometry_msgs/msg/TransformStamped")(
        header=convert.header(stamp_ns, parent), child_frame_id=child, transform=convert.transform_message(T_parent_child)
    )


def tf_message(transforms: list[object]) -> object:
    """tf2_msgs/TFMessage of TransformStamped messages."""
    return message_class(TF_MESSAGE)(transforms=transforms)


def image_message(stamp_ns: int, values: np.ndarray, encoding: str, frame: str) -> object:
    """sensor_msgs/Image of contiguous little-endian ``values`` (H, W) or (H, W, C) in ``encoding``, rows unpadded
    (e.g. RGB uint8 as ``rgb8``, millimetres uint16 as ``16UC1``, metres float32 as ``32FC1``)."""
    values = np.ascontiguousarray(values)
    height, width = values.shape[:2]
    return message_class(IMAGE)(
        header=convert.header(stamp_ns, frame),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=values.nbytes // height,
        data=values.view(np.uint8).reshape(-1),
    )


def compressed_image_message(stamp_ns: int, data: bytes, fmt: str, frame: str) -> object:
    """sensor_msgs/CompressedImage of encoded bytes (``fmt``: jpeg or png)."""
    return message_class("sensor_msgs/msg/CompressedImage")(header=convert.header(stamp_ns, frame), format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def camera_info_message(stamp_ns: int, intrinsics: PinholeIntrinsics, frame: str, distortion: np.ndarray | None = None) -> object:
    """sensor_msgs/CameraInfo of a pinhole camera with plumb_bob ``distortion`` (5,) (None: undistorted), R identity, P = [K | 0]."""
    k = np.array([intrinsics.fx, 0.0, intrinsics.cx, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0, 1.0])
    p = np.array([intrinsics.fx, 0.0, intrinsics.cx, 0.0, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    roi = message_class("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return message_class(CAMERA_INFO)(
        header=convert.header(stamp_ns, frame),
        height=intrinsics.height,
        width=intrinsics.width,
        distortion_model="plumb_bob",
        d=np.zeros(5) if distortion is None else np.asarray(distortion, dtype=np.float64),
        k=k,
        r=np.eye(3).reshape(-1),
        p=p,
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
