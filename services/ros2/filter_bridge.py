"""The filter's ROS 2 face: ROS messages in (odometry, images, initial pose, the global
localization service) translated to locnerf's messages, and locnerf's pose and particles out as
nav2_amcl publishes them (``amcl_pose``, ``particle_cloud`` as nav2_msgs/ParticleCloud, ``map → odom`` on ``/tf``).

Frames (REP 103/105; docs/ROS2.md draws them): ``map`` is locnerf's metric world frame, ``odom``
the VIO's frame, ``base_link`` the body, and the camera is ``T_body_cam`` from the body (OpenGL
axes inside locnerf). With the camera pose ``T_map_cam`` from the filter and the odometry
``T_odom_base`` at the same stamp:

    T_map_base = T_map_cam · T_body_cam⁻¹,   T_map_odom = T_map_base · T_odom_base⁻¹   (as nav2_amcl)

and, as nav2_amcl, ``map → odom`` is stamped ``stamp + transform_tolerance`` (future-dated).

Translation runs on the filter thread; the transport callbacks only enqueue. Every failure raises
:class:`DecodeError` with a ``ros2_*`` kind, which the driver counts in the filter's bad-message
counters (visible in FilterStatus).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

from locnerf.geometry.se3 import adjoint, pose_inverse
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode, encode
from locnerf.messages.schemas import (
    GlobalLocalizationCommand,
    InitialPoseCommand,
    PoseEstimate,
)
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.ros2 import convert
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import check_key
from locnerf.ros2.types import EMPTY_SERVICE, NAV2_PARTICLE, NAV2_PARTICLE_CLOUD, TF_MESSAGE, message_class, serialize
from locnerf.ros2.types import POSE_WITH_COVARIANCE_STAMPED as POSE_WITH_COVARIANCE
from locnerf_services.filter_loop.service import FilterLoop
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.ros2.sensors import Arrive, ImageArrived, Received, Ros2Sensors, open_sample
from locnerf_services.transport import Bus

POSE_ARRAY = "geometry_msgs/msg/PoseArray"


class FilterRos2Bridge:
    """Translates between a :class:`FilterLoop` and ROS 2 topics on ``bus``.

    ``odometry``, ``camera_info`` and ``depth_camera_info`` translate sensor samples
    (:class:`Ros2Sensors`), ``initial_pose`` and ``global_localization`` the commands; the driver
    calls them by kind. Images go through :attr:`sensors` (``image``, ``take_depth``, ``paired_image``).

    Args:
        loop: the filter (its T_body_cam, odometry history, particles and bad-message counters).
        bus: the Zenoh session.
        config: topics, domain, frames.
        clock: monotonic wall-clock seconds (the wait of a colour image for its depth image).
    """

    def __init__(self, loop: FilterLoop, bus: Bus, config: Ros2Config, clock: Callable[[], float] = time.monotonic) -> None:
        self.loop = loop
        self.config = config
        self.node = Ros2Node(bus, config.domain_id, config.node_name, config.namespace)
        self.T_body_cam = loop.frames.T_body_cam
        self.T_cam_body = pose_inverse(loop.frames.T_body_cam)
        self.pose_publisher = self.node.publisher(config.pose_topic, POSE_WITH_COVARIANCE)
        self.particles_publisher = self.node.publisher(config.particles_topic, NAV2_PARTICLE_CLOUD)
        self.legacy_particles_publisher = self.node.publisher(config.legacy_particles_topic, POSE_ARRAY) if config.legacy_particles_topic else None
        self.tf_publisher = self.node.publisher(config.tf_topic, TF_MESSAGE) if config.publish_tf else None
        self.sensors = Ros2Sensors(self.node, config, clock)
        self.odometry, self.camera_info = self.sensors.odometry, self.sensors.camera_info
        self.depth_camera_info = self.sensors.depth_camera_info
        self.names: dict[str, str] = {}

    # ------------------------------------------------------------------ wiring
    def subscribe(self, arrive: Arrive, image_arrived: ImageArrived, depth_arrived: Callable[[], None]) -> None:
        """Declare the subscriptions and the service; callbacks only enqueue.

        Args:
            arrive: ``arrive(urgent, kind, key, (payload, attachment))`` queues a message for the filter thread.
            image_arrived: ``image_arrived(key, (payload, attachment))`` keeps the newest colour image.
            depth_arrived: ``depth_arrived()`` announces a depth image kept by :attr:`sensors` (``take_depth`` takes it).
        """
        config = self.config
        self.names["initial_pose"] = self.node.subscription(
            config.initial_pose_topic, POSE_WITH_COVARIANCE, lambda key, payload, attachment: arrive(False, "initial_pose", key, (payload, attachment))
        )
        if config.sensors:
            self.sensors.subscribe(arrive, image_arrived, depth_arrived)
        response = serialize(message_class(f"{EMPTY_SERVICE}_Response")(), f"{EMPTY_SERVICE}_Response")

        def global_localization(key: str, payload: bytes, _request: Attachment | None) -> bytes | None:
            arrive(False, "global_localization", key, (payload, None))  # checked and counted on the filter thread
            try:
                check_key(key, config.domain_id, self.names["global_localization"], EMPTY_SERVICE)
            except DecodeError:
                return None
            return response

        self.names["global_localization"] = self.node.resolve(config.global_localization_service)
        self.node.service(config.global_localization_service, EMPTY_SERVICE, global_localization)

    def close(self) -> None:
        """Undeclare the node's entities."""
        self.node.close()

    # ------------------------------------------------------------------ in (filter thread)
    def initial_pose(self, key: str, received: Received) -> bytes:
        """PoseWithCovarianceStamped of the body in the map -> locnerf InitialPoseCommand of the camera."""
        message = open_sample(key, received, self.config.domain_id, self.names["initial_pose"], POSE_WITH_COVARIANCE)
        if message.header.frame_id.lstrip("/") != self.config.global_frame_id:
            raise DecodeError("ros2_frame", f"initial pose in frame {message.header.frame_id!r}, expected {self.config.global_frame_id!r}")
        T_map_base = convert.pose_from_message(message.pose.pose)
        covariance_body = convert.covariance_from_ros(message.pose.covariance, T_map_base)
        to_camera = adjoint(self.T_cam_body)  # δ_cam = Ad(T_body_cam⁻¹) δ_body
        covariance = to_camera @ covariance_body @ to_camera.T
        T_map_cam = T_map_base @ self.T_body_cam
        try:
            command = InitialPoseCommand(
                stamp_ns=convert.nanoseconds(message.header.stamp),
                T_world_cam=T_map_cam.tolist(),
                covariance=(0.5 * (covariance + covariance.T)).tolist(),
            )
        except ValueError as error:
            raise DecodeError("ros2_invalid", f"initial pose: {error}") from None
        return encode(command)

    def global_localization(self, key: str, _received: Received) -> bytes:
        """The service was called (on its key with the right type hash): a locnerf GlobalLocalizationCommand."""
        check_key(key, self.config.domain_id, self.names["global_localization"], EMPTY_SERVICE)
        return encode(GlobalLocalizationCommand(stamp_ns=self.loop.latest_stamp_ns))

    # ------------------------------------------------------------------ out (filter thread)
    def publish_outputs(self, outgoing: list[tuple[str, bytes]]) -> None:
        """Publish the ROS 2 counterparts of the filter's pose and particle messages in ``outgoing``."""
        pose_key, particles_key = keys.key(self.loop.robot_id, keys.POSE), keys.key(self.loop.robot_id, keys.PARTICLES)
        for key, payload in outgoing:
            if key == pose_key:
                self._publish_pose(decode(payload, PoseEstimate))
            elif key == particles_key and self.loop.running:
                self._publish_particles()

    def _publish_pose(self, estimate: PoseEstimate) -> None:
        T_map_cam = torch.tensor(estimate.T_world_cam, dtype=torch.float64)
        T_map_base = T_map_cam @ self.T_cam_body
        to_body = adjoint(self.T_body_cam)  # δ_body = Ad(T_body_cam) δ_cam
        covariance = to_body @ torch.tensor(estimate.covariance, dtype=torch.float64) @ to_body.T
        pose_type = message_class("geometry_msgs/msg/PoseWithCovariance")
        self.pose_publisher.publish(
            message_class(POSE_WITH_COVARIANCE)(
                header=convert.header(estimate.stamp_ns, self.config.global_frame_id),
                pose=pose_type(pose=convert.pose_message(T_map_base), covariance=convert.covariance_to_ros(covariance, T_map_base)),
            )
        )
        T_odom_cam = self.loop.history.latest_pose
        if self.tf_publisher is None or T_odom_cam is None:
            return
        T_odom_base = T_odom_cam @ self.T_cam_body
        T_map_odom = T_map_base @ pose_inverse(T_odom_base)
        transform = message_class("geometry_msgs/msg/TransformStamped")(
            header=convert.header(estimate.stamp_ns + nanoseconds_from_seconds(self.config.transform_tolerance), self.config.global_frame_id),
            child_frame_id=self.config.odom_frame_id,
            transform=convert.transform_message(T_map_odom),
        )
        self.tf_publisher.publish(message_class(TF_MESSAGE)(transforms=[transform]))

    def _publish_particles(self) -> None:
        """The particles' body poses and normalised weights as nav2_msgs/ParticleCloud (and as a PoseArray on legacy_particles_topic)."""
        poses = [convert.pose_message(pose) for pose in self.loop.metric_particle_poses() @ self.T_cam_body]
        weights = self.loop.localizer.particles.weights.double().cpu().tolist()
        header = convert.header(self.loop.latest_stamp_ns, self.config.global_frame_id)
        particle = message_class(NAV2_PARTICLE)
        particles = [particle(pose=pose, weight=weight) for pose, weight in zip(poses, weights, strict=True)]
        self.particles_publisher.publish(message_class(NAV2_PARTICLE_CLOUD)(header=header, particles=particles))
        if self.legacy_particles_publisher is not None:
            self.legacy_particles_publisher.publish(message_class(POSE_ARRAY)(header=header, poses=poses))
