"""Settings of the filter's ROS 2 interface (topic names and frames default to nav2_amcl's)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from locnerf.geometry.validation import validate_pose_setting


class Ros2Config(BaseModel):
    """ROS 2 over rmw_zenoh: which topics the filter reads and writes, in which domain and frames."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(False, description="Speak ROS 2 on the Zenoh session (publish amcl_pose, particle_cloud, /tf; serve the commands).")
    sensors: bool = Field(True, description="When enabled, also read odometry and camera topics (the filter is then its own ROS 2 ingest).")
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID of the ROS 2 graph.")
    namespace: str = Field("", description="Namespace of the node and of its relative topic names, e.g. /robot1 ('' = global).")
    node_name: str = Field("locnerf", description="Node name shown by `ros2 node list`.")
    odometry_topic: str = Field(
        "odom",
        description="nav_msgs/msg/Odometry of the VIO (pose of base_frame_id in odom_frame_id); '' = none: an RGB-D camera without VIO, "
        "whose odometry the ingest computes from the colour and depth frames (IngestConfig odometry.ros2_frames).",
    )
    image_topic: str = Field("camera/image_raw", description="sensor_msgs/msg/Image (rgb8, bgr8, mono8) or, with compressed, its /compressed topic.")
    image_transport: Literal["raw", "compressed"] = Field(
        "raw", description="raw: sensor_msgs/msg/Image; compressed: sensor_msgs/msg/CompressedImage (jpeg, png)."
    )
    camera_info_topic: str = Field("camera/camera_info", description="sensor_msgs/msg/CameraInfo with the intrinsics and distortion of the images.")
    image_rectified: bool | None = Field(
        None,
        description="The images are already rectified (image_proc's image_rect, image_rect_color): taken as they are with the camera info's P, "
        "never undistorted; False: raw images, undistorted onto P as image_proc does; None: True when a segment of image_topic starts "
        "with 'image_rect'.",
    )
    depth_topic: str = Field(
        "",
        description="sensor_msgs/msg/Image of depth (16UC1 or mono16 millimetres, 32FC1 metres) paired with the colour images by stamp, "
        "e.g. camera/aligned_depth_to_color/image_raw (a RealSense's depth registered to its colour camera); '' = colour only.",
    )
    depth_camera_info_topic: str = Field(
        "",
        description="sensor_msgs/msg/CameraInfo of the depth camera ('' = the depth image is registered to the colour camera: "
        "it has the colour image's size and takes the colour camera's intrinsics and distortion).",
    )
    depth_rectified: bool | None = Field(
        None,
        description="With depth_camera_info_topic: the depth images are already rectified, as image_rectified for the colour images "
        "(None: True when a segment of depth_topic starts with 'image_rect', e.g. a RealSense's depth/image_rect_raw). "
        "A registered depth image follows image_rectified.",
    )
    T_colour_depth: list[list[float]] | None = Field(
        None,
        description="With depth_camera_info_topic: 4×4 pose of the depth camera's optical frame in the colour camera's optical frame "
        "(ROS optical axes, as OpenCV: x right, y down, z forward), metres; None: the two cameras share their pose. "
        "Converted to locnerf's OpenGL axes for the depth image's header.",
    )
    depth_pairing_tolerance: float = Field(
        0.02, ge=0, description="Largest stamp difference between a colour image and the depth image paired with it, seconds."
    )
    depth_max_wait: float = Field(
        0.1,
        ge=0,
        description="Longest wall-clock wait for a colour image's depth image, seconds; after it the colour image goes on alone "
        "(counted as images_without_depth).",
    )
    initial_pose_topic: str = Field(
        "initialpose", description="geometry_msgs/msg/PoseWithCovarianceStamped of base_frame_id in global_frame_id (RViz's 2D Pose Estimate)."
    )
    pose_topic: str = Field("amcl_pose", description="geometry_msgs/msg/PoseWithCovarianceStamped published at the odometry rate.")
    particles_topic: str = Field(
        "particle_cloud", description="nav2_msgs/msg/ParticleCloud of the particles (base frame poses and normalised weights), as nav2_amcl."
    )
    legacy_particles_topic: str = Field(
        "",
        description="Also publish the particles as a geometry_msgs/msg/PoseArray on this topic (nav2_amcl's former 'particlecloud', "
        "for RViz's PoseArray display); '' = not published.",
    )
    tf_topic: str = Field("/tf", description="tf2_msgs/msg/TFMessage carrying global_frame_id -> odom_frame_id.")
    global_localization_service: str = Field(
        "reinitialize_global_localization", description="std_srvs/srv/Empty service that re-initialises over the whole map."
    )
    global_frame_id: str = Field("map", description="The map frame (locnerf's metric world frame).")
    odom_frame_id: str = Field("odom", description="The odometry frame of the VIO.")
    base_frame_id: str = Field("base_link", description="The robot body frame (T_body_cam relates it to the camera).")
    publish_tf: bool = Field(True, description="Publish map -> odom on tf_topic, as nav2_amcl's tf_broadcast.")
    transform_tolerance: float = Field(
        1.0,
        ge=0,
        description="Seconds by which map -> odom is future-dated (stamped odometry stamp + transform_tolerance), as nav2_amcl's "
        "transform_tolerance (default 1.0): tf lookups of map -> base_link at sensor stamps newer than the last odometry then interpolate "
        "instead of failing as an extrapolation into the future.",
    )

    @field_validator("T_colour_depth")
    @classmethod
    def _extrinsic(cls, value: list[list[float]] | None) -> list[list[float]] | None:
        return None if value is None else validate_pose_setting(value, "T_colour_depth")

    @model_validator(mode="after")
    def _depth_camera(self) -> Ros2Config:
        if self.T_colour_depth is not None and not self.depth_camera_info_topic:
            raise ValueError("T_colour_depth is set but depth_camera_info_topic is '': a depth image registered to the colour camera has its pose")
        if self.depth_rectified is not None and not self.depth_camera_info_topic:
            raise ValueError("depth_rectified is set but depth_camera_info_topic is '': a registered depth image follows image_rectified")
        return self

    @property
    def images_rectified(self) -> bool:
        """Whether the colour images (and a depth image registered to them) are already rectified."""
        return rectified_topic(self.image_topic) if self.image_rectified is None else self.image_rectified

    @property
    def depth_images_rectified(self) -> bool:
        """Whether the depth images of depth_camera_info_topic's camera are already rectified."""
        return rectified_topic(self.depth_topic) if self.depth_rectified is None else self.depth_rectified


def rectified_topic(name: str) -> bool:
    """Whether a topic name says rectified images: a segment starting with ``image_rect`` (image_proc's
    ``image_rect``, ``image_rect_color``, a RealSense's ``image_rect_raw``, their ``/compressed``)."""
    return any(segment.startswith("image_rect") for segment in name.split("/"))
