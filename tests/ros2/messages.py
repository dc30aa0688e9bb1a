"""ROS 2 test messages made with rosbags: what a VIO, a camera driver and RViz would publish."""

from __future__ import annotations

import numpy as np
import torch

from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2 import convert
from locnerf.ros2.types import message_class


def odometry(stamp: float, T_odom_base: torch.Tensor, odom_frame: str = "odom", base_frame: str = "base_link") -> object:
    """nav_msgs/Odometry with the pose ``T_odom_base`` (4, 4) and zero twist."""
    pose = message_class("geometry_msgs/msg/PoseWithCovariance")(pose=convert.pose_message(T_odom_base), covariance=np.zeros(36))
    vector = message_class("geometry_msgs/msg/Vector3")
    twist = message_class("geometry_msgs/msg/Twist")(linear=vector(0.0, 0.0, 0.0), angular=vector(0.0, 0.0, 0.0))
    return message_class("nav_msgs/msg/Odometry")(
        header=convert.header(nanoseconds_from_seconds(stamp), odom_frame),
        child_frame_id=base_frame,
        pose=pose,
        twist=message_class("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)),
    )


def image(stamp: float, pixels: np.ndarray, encoding: str = "rgb8", frame: str = "camera_optical_frame") -> object:
    """sensor_msgs/Image of RGB pixels (H, W, 3) uint8, written as ``encoding`` (rgb8 or bgr8)."""
    return _image_message(stamp, frame, encoding, np.ascontiguousarray(pixels[..., ::-1] if encoding == "bgr8" else pixels))


def depth_image(stamp: float, depth: np.ndarray, encoding: str = "16UC1", frame: str = "camera_optical_frame") -> object:
    """sensor_msgs/Image of a depth image (H, W): millimetres for 16UC1 and mono16, metres for 32FC1 (little-endian)."""
    return _image_message(stamp, frame, encoding, np.ascontiguousarray(depth, dtype="<f4" if encoding == "32FC1" else "<u2"))


def _image_message(stamp: float, frame: str, encoding: str, values: np.ndarray) -> object:
    """sensor_msgs/Image of the contiguous little-endian ``values`` (H, W) or (H, W, C), rows unpadded."""
    height, width = values.shape[:2]
    return message_class("sensor_msgs/msg/Image")(
        header=convert.header(nanoseconds_from_seconds(stamp), frame),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=values.nbytes // height,
        data=values.view(np.uint8).reshape(-1),
    )


def camera_info(stamp: float, intrinsics: PinholeIntrinsics, frame: str = "camera_optical_frame", distortion: np.ndarray | None = None) -> object:
    """sensor_msgs/CameraInfo of a pinhole camera with plumb_bob ``distortion`` (5,) (None: undistorted)."""
    k = np.array([intrinsics.fx, 0.0, intrinsics.cx, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0, 1.0])
    p = np.array([intrinsics.fx, 0.0, intrinsics.cx, 0.0, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    roi = message_class("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return message_class("sensor_msgs/msg/CameraInfo")(
        header=convert.header(nanoseconds_from_seconds(stamp), frame),
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


def initial_pose(stamp: float, T_map_base: torch.Tensor, covariance_ros: list[float], frame: str = "map") -> object:
    """geometry_msgs/PoseWithCovarianceStamped, as RViz's 2D Pose Estimate sends it."""
    pose = message_class("geometry_msgs/msg/PoseWithCovariance")(pose=convert.pose_message(T_map_base), covariance=np.asarray(covariance_ros, dtype=np.float64))
    return message_class("geometry_msgs/msg/PoseWithCovarianceStamped")(header=convert.header(nanoseconds_from_seconds(stamp), frame), pose=pose)
