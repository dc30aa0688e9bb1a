"""ROS 2 test messages made with rosbags: what a VIO, a camera driver and RViz would publish
(the library's builders, :mod:`locnerf.ros2.messages`, with stamps in float seconds)."""

from __future__ import annotations

import numpy as np
import torch

from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2 import convert
from locnerf.ros2 import messages as build
from locnerf.ros2.types import message_class


def odometry(stamp: float, T_odom_base: torch.Tensor, odom_frame: str = "odom", base_frame: str = "base_link") -> object:
    """nav_msgs/Odometry with the pose ``T_odom_base`` (4, 4) and zero twist."""
    return build.odometry_message(nanoseconds_from_seconds(stamp), T_odom_base, odom_frame, base_frame)


def image(stamp: float, pixels: np.ndarray, encoding: str = "rgb8", frame: str = "camera_optical_frame") -> object:
    """sensor_msgs/Image of RGB pixels (H, W, 3) uint8, written as ``encoding`` (rgb8 or bgr8)."""
    return build.image_message(nanoseconds_from_seconds(stamp), pixels[..., ::-1] if encoding == "bgr8" else pixels, encoding, frame)


def depth_image(stamp: float, depth: np.ndarray, encoding: str = "16UC1", frame: str = "camera_optical_frame") -> object:
    """sensor_msgs/Image of a depth image (H, W): millimetres for 16UC1 and mono16, metres for 32FC1 (little-endian)."""
    return build.image_message(nanoseconds_from_seconds(stamp), np.asarray(depth, dtype="<f4" if encoding == "32FC1" else "<u2"), encoding, frame)


def camera_info(stamp: float, intrinsics: PinholeIntrinsics, frame: str = "camera_optical_frame", distortion: np.ndarray | None = None) -> object:
    """sensor_msgs/CameraInfo of a pinhole camera with plumb_bob ``distortion`` (5,) (None: undistorted)."""
    return build.camera_info_message(nanoseconds_from_seconds(stamp), intrinsics, frame, distortion)


def initial_pose(stamp: float, T_map_base: torch.Tensor, covariance_ros: list[float], frame: str = "map") -> object:
    """geometry_msgs/PoseWithCovarianceStamped, as RViz's 2D Pose Estimate sends it."""
    pose = message_class("geometry_msgs/msg/PoseWithCovariance")(pose=convert.pose_message(T_map_base), covariance=np.asarray(covariance_ros, dtype=np.float64))
    return message_class("geometry_msgs/msg/PoseWithCovarianceStamped")(header=convert.header(nanoseconds_from_seconds(stamp), frame), pose=pose)
