"""A ROS 2 RGB-D camera driver for tests: RealSense's topic layout, publishing on any Bus with rmw_zenoh keys."""

from __future__ import annotations

import numpy as np

from locnerf.render.camera import PinholeIntrinsics
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.transport import Bus
from tests.ros2 import messages

IMAGE, CAMERA_INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"
COLOUR_TOPIC, COLOUR_INFO_TOPIC = "camera/camera/color/image_raw", "camera/camera/color/camera_info"
ALIGNED_DEPTH_TOPIC = "camera/camera/aligned_depth_to_color/image_raw"
DEPTH_TOPIC, DEPTH_INFO_TOPIC = "camera/camera/depth/image_rect_raw", "camera/camera/depth/camera_info"


def rgbd_config(registered: bool = True, **fields: object) -> Ros2Config:
    """A Ros2Config reading the camera: the aligned depth (registered) or the depth camera's own stream."""
    depth = {"depth_topic": ALIGNED_DEPTH_TOPIC} if registered else {"depth_topic": DEPTH_TOPIC, "depth_camera_info_topic": DEPTH_INFO_TOPIC}
    return Ros2Config(image_topic=COLOUR_TOPIC, camera_info_topic=COLOUR_INFO_TOPIC, **depth, **fields)


class RgbdCamera:
    """Publishers of a ``realsense2_camera`` node: colour image and camera info, depth image (and, for
    unregistered depth, its camera info) on the topics of ``config``.

    Args:
        bus: where to publish.
        config: topic names and domain (:func:`rgbd_config`).
    """

    def __init__(self, bus: Bus, config: Ros2Config) -> None:
        self.node = Ros2Node(bus, config.domain_id, "camera", "/camera")
        self.colour = self.node.publisher("/" + config.image_topic, IMAGE)
        self.colour_info = self.node.publisher("/" + config.camera_info_topic, CAMERA_INFO)
        self.depth = self.node.publisher("/" + config.depth_topic, IMAGE)
        self.depth_info = self.node.publisher("/" + config.depth_camera_info_topic, CAMERA_INFO) if config.depth_camera_info_topic else None

    def infos(self, stamp: float, colour: PinholeIntrinsics, depth: PinholeIntrinsics | None = None, distortion: np.ndarray | None = None) -> None:
        """The camera infos (the colour camera with plumb_bob ``distortion`` (5,), None: undistorted)."""
        self.colour_info.publish(messages.camera_info(stamp, colour, "camera_color_optical_frame", distortion))
        if self.depth_info is not None and depth is not None:
            self.depth_info.publish(messages.camera_info(stamp, depth, "camera_depth_optical_frame"))

    def colour_image(self, stamp: float, pixels: np.ndarray) -> None:
        """An rgb8 colour image (H, W, 3) uint8."""
        self.colour.publish(messages.image(stamp, pixels, frame="camera_color_optical_frame"))

    def depth_image(self, stamp: float, depth: np.ndarray, encoding: str = "16UC1") -> None:
        """A depth image (H, W): uint16 millimetres (16UC1, mono16) or float32 metres (32FC1)."""
        self.depth.publish(messages.depth_image(stamp, depth, encoding, "camera_depth_optical_frame"))
