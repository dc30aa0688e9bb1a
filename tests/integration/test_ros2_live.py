"""ROS 2 on the same Zenoh, with real processes on loopback: a test publisher plays a VIO and a
camera driver (CDR made with rosbags, rmw_zenoh keys and attachments) into a filter with ROS 2
enabled and one worker; a test subscriber decodes amcl_pose, particle_cloud and /tf with rosbags.

Tolerances: as tests/integration/test_services_live.py, "tracking" is 15 consecutive amcl_poses
(1 s) within 0.15 m and 3° of the ground truth of the same stamp. The filter starts from a ROS
initialpose 0.1 m and ~3° off the truth with σ = 0.1 m, 0.05 rad (T_body_cam = identity, so
base_link is the camera and amcl_pose is comparable with the camera's ground truth).
"""

from __future__ import annotations

import threading

import numpy as np
import torch

from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.geometry.se3 import make_pose
from locnerf.geometry.so3 import so3_exp
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.ros2 import convert
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import EntityKind, data_key, fully_qualified_name
from locnerf.ros2.types import (
    dds_type_name,
    deserialize,
    message_class,
    serialize,
    type_hash,
)
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.sensor_ingest.service import Pacer
from locnerf_services.sensor_ingest.world_source import WorldSourceConfig, world_events
from locnerf_services.supervisor import write_config
from locnerf_services.transport import TransportConfig
from tests.integration.conftest import ROBOT, wait_for
from tests.ros2 import messages
from tests.ros2.rmw_client import RmwServiceClient

EPOCH = 1_700_000_000.0  # ROS stamps are UNIX time: the stream's stamps are offset by this
TRACKED_TRANSLATION, TRACKED_ROTATION_DEG = 0.15, 3.0
OUTPUTS = {
    "amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "particle_cloud": "nav2_msgs/msg/ParticleCloud",
    "tf": "tf2_msgs/msg/TFMessage",
}
TOKENS = {  # (kind, topic, type) the filter's node must announce
    (EntityKind.PUBLISHER, "/amcl_pose", OUTPUTS["amcl_pose"]),
    (EntityKind.PUBLISHER, "/particle_cloud", OUTPUTS["particle_cloud"]),
    (EntityKind.PUBLISHER, "/tf", OUTPUTS["tf"]),
    (EntityKind.SUBSCRIPTION, "/odom", "nav_msgs/msg/Odometry"),
    (EntityKind.SUBSCRIPTION, "/camera/image_raw", "sensor_msgs/msg/Image"),
    (EntityKind.SUBSCRIPTION, "/camera/camera_info", "sensor_msgs/msg/CameraInfo"),
    (EntityKind.SUBSCRIPTION, "/initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
    (EntityKind.SERVICE_SERVER, "/reinitialize_global_localization", "std_srvs/srv/Empty"),
}


class RosObserver:
    """The decoded ROS outputs of the filter and the ground truth of the stream, by stamp."""

    def __init__(self, bus) -> None:
        self.lock = threading.Lock()
        self.received: dict[str, list] = {name: [] for name in OUTPUTS}
        self.truth: dict[int, torch.Tensor] = {}
        self.odometry: dict[int, torch.Tensor] = {}
        self.tokens: set[str] = set()
        for name, ros_type in OUTPUTS.items():
            bus.subscribe_attached(
                data_key(0, "/" + name, ros_type),
                lambda _k, payload, attachment, name=name, ros_type=ros_type: self._store(name, ros_type, payload, attachment),
            )
        bus.watch_liveliness("@ros2_lv/0/**", lambda key, alive: self._token(key, alive))

    def _store(self, name: str, ros_type: str, payload: bytes, attachment: bytes | None) -> None:
        message = deserialize(payload, ros_type)
        Attachment.decode(attachment)
        with self.lock:
            self.received[name].append(message)

    def _token(self, key: str, alive: bool) -> None:
        with self.lock:
            (self.tokens.add if alive else self.tokens.discard)(key)

    def errors(self, count: int) -> list[tuple[float, float]]:
        """(translation, rotation °) of the last ``count`` amcl_poses that have ground truth."""
        out = []
        with self.lock:
            poses = self.received["amcl_pose"][-count:]
        for message in poses:
            truth = self.truth.get(convert.nanoseconds(message.header.stamp))
            if truth is not None:
                estimate = convert.pose_from_message(message.pose.pose)
                out.append((float(translation_error(estimate, truth)), float(rotation_error_deg(estimate, truth))))
        return out

    def tracking(self) -> bool:
        window = self.errors(15)
        return len(window) == 15 and all(t < TRACKED_TRANSLATION and r < TRACKED_ROTATION_DEG for t, r in window)


class RosSensors:
    """A VIO and a camera driver: the procedural world's stream as ROS 2 messages, in real time."""

    def __init__(self, bus, observer: RosObserver) -> None:
        self.node = Ros2Node(bus, 0, "sim_sensors")
        self.odom = self.node.publisher("odom", "nav_msgs/msg/Odometry")
        self.image = self.node.publisher("camera/image_raw", "sensor_msgs/msg/Image")
        self.info = self.node.publisher("camera/camera_info", "sensor_msgs/msg/CameraInfo")
        self.initial = self.node.publisher("initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped")
        self.observer = observer
        self.stop = threading.Event()
        self.frames = 0
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        events = world_events(ProceduralWorld.default(), WorldSourceConfig(duration=120.0), seed=3)
        for event in Pacer(1.0).paced(events, self.stop.is_set):
            stamp = EPOCH + event.stamp
            if isinstance(event, GroundTruthEvent):
                self.observer.truth[nanoseconds_from_seconds(stamp)] = event.T_world_cam
            elif isinstance(event, OdometryEvent):
                self.observer.odometry[nanoseconds_from_seconds(stamp)] = event.T_odom_body
                self.odom.publish(messages.odometry(stamp, event.T_odom_body))
            elif isinstance(event, ImageEvent):
                self.info.publish(messages.camera_info(stamp, event.intrinsics))
                self.image.publish(messages.image(stamp, event.pixels, encoding=("rgb8", "bgr8")[self.frames % 2]))
                self.frames += 1


def filter_config(tmp_path):
    config = FilterProcessConfig(loop=FilterLoopConfig(start="wait", update_timeout=3.0), ros2=Ros2Config(enabled=True))
    return write_config(tmp_path / "filter_ros2.toml", config)


def check_tokens(tokens: set[str]) -> None:
    """Field by field against docs/ROS2.md (rmw_zenoh design.md): one NN token of node locnerf
    and an entity token per TOKENS row, all of one session and node id."""
    ours = [token.split("/") for token in tokens if token.split("/")[8:9] == ["locnerf"]]
    nodes = [parts for parts in ours if parts[5] == "NN"]
    assert len(nodes) == 1, tokens
    node = nodes[0]
    assert node[:2] == ["@ros2_lv", "0"] and int(node[2], 16) > 0 and node[3] == node[4] == "0" and node[6:8] == ["%", "%"] and len(node) == 9
    entities = {(EntityKind(parts[5]), parts[9].replace("%", "/"), parts[10], parts[11]) for parts in ours if parts[5] != "NN"}
    assert entities == {(kind, name, dds_type_name(ros_type), type_hash(ros_type)) for kind, name, ros_type in TOKENS}
    for parts in ours:
        assert parts[2] == node[2] and parts[3] == "0" and parts[6:9] == ["%", "%", "locnerf"]
        if parts[5] != "NN":
            assert len(parts) == 13 and parts[12] == "::,10:,:,:,," and int(parts[4]) > 0
    assert len({parts[4] for parts in ours if parts[5] != "NN"}) == len(TOKENS), "entity ids are unique"


def test_ros2_topics_in_and_out_converge_count_bad_input_and_serve_the_service(hub, tmp_path):
    stack, observer, bus = hub
    ros = RosObserver(bus)
    stack.start("filter", "run", "filter", "--robot-id", ROBOT, "--device", "cpu", "--localizer", "llff", "--config", str(filter_config(tmp_path)))
    stack.start("wa", "run", "worker", "--robot-id", ROBOT, "--device", "cpu", "--worker-id", "wa")
    wait_for(lambda: observer.workers() == ["wa"], 120, "the filter to see worker wa", stack)
    wait_for(lambda: sum("/locnerf" in t for t in ros.tokens) == 1 + len(TOKENS), 30, "the locnerf node's liveliness tokens", stack)
    with ros.lock:
        check_tokens(set(ros.tokens))

    sensors = RosSensors(bus, ros)
    sensors.thread.start()
    try:
        wait_for(lambda: sensors.frames >= 2 and len(ros.truth) > 0, 30, "the stream to start", stack)
        truth = ros.truth[max(ros.truth)]
        offset = make_pose(so3_exp(torch.tensor([0.0, 0.05, 0.0], dtype=torch.float64)), torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64))
        covariance = np.diag([0.01, 0.01, 0.01, 0.0025, 0.0025, 0.0025]).reshape(-1)
        sensors.initial.publish(messages.initial_pose(EPOCH, truth @ offset, covariance.tolist()))
        wait_for(ros.tracking, 60, "amcl_pose to converge on the ground truth", stack)

        # /tf: map -> odom composes with the odometry of the same stamp into amcl_pose; it is stamped
        # transform_tolerance (1 s) after that stamp, as nav2_amcl future-dates it.
        with ros.lock:
            transforms = {convert.nanoseconds(m.transforms[0].header.stamp) - 1_000_000_000: m.transforms[0] for m in ros.received["tf"]}
            pose = next(m for m in reversed(ros.received["amcl_pose"]) if convert.nanoseconds(m.header.stamp) in transforms)
            tf, cloud = transforms[convert.nanoseconds(pose.header.stamp)], ros.received["particle_cloud"]
        assert (tf.header.frame_id, tf.child_frame_id) == ("map", "odom") and cloud and len(cloud[-1].particles) > 0
        rotation, translation = tf.transform.rotation, tf.transform.translation
        as_pose = message_class("geometry_msgs/msg/Pose")(
            position=message_class("geometry_msgs/msg/Point")(translation.x, translation.y, translation.z), orientation=rotation
        )
        T_odom_base = ros.odometry[convert.nanoseconds(pose.header.stamp)]
        assert torch.allclose(convert.pose_from_message(as_pose) @ T_odom_base, convert.pose_from_message(pose.pose.pose), atol=1e-6)

        # Bad input on the ROS topics: counted in FilterStatus, dropped, the filter keeps going.
        valid = Attachment(1, 0, bytes(16)).encode()
        bus.publish(sensors.odom.key, b"\x00\x01\x00\x00 not an odometry", valid)
        wrong_hash = sensors.odom.key.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
        bus.publish(wrong_hash, serialize(messages.odometry(EPOCH, torch.eye(4, dtype=torch.float64)), "nav_msgs/msg/Odometry"), valid)
        odd = messages.image(EPOCH, np.zeros((120, 160, 3), np.uint8))
        odd.encoding = "yuv422"
        bus.publish(sensors.image.key, serialize(odd, "sensor_msgs/msg/Image"), valid)
        counters = ("bad_ros2_cdr", "bad_ros2_type_hash", "bad_ros2_encoding")
        wait_for(lambda: all(observer.counter(name) >= 1 for name in counters), 30, f"{counters} in FilterStatus", stack)
        wait_for(ros.tracking, 30, "tracking after the bad input", stack)

        # The service: an Empty request on rmw_zenoh's key, replied with an Empty response; the filter re-initialises.
        epoch = observer.poses[-1].epoch
        key = data_key(0, fully_qualified_name("reinitialize_global_localization"), "std_srvs/srv/Empty")
        request = serialize(message_class("std_srvs/srv/Empty_Request")(), "std_srvs/srv/Empty_Request")
        client = RmwServiceClient(TransportConfig(connect=(stack.endpoint,)))  # as `ros2 service call` queries
        try:
            replies = client.call(key, request, Attachment(5, 0, bytes(range(16))).encode(), timeout=10.0)
        finally:
            client.close()
        assert len(replies) == 1 and deserialize(replies[0][1], "std_srvs/srv/Empty_Response") is not None
        assert Attachment.decode(replies[0][2]).sequence_number == 5
        wait_for(lambda: observer.poses[-1].epoch == epoch + 1, 30, "re-initialisation over the map", stack)
    finally:
        sensors.stop.set()
        sensors.thread.join(timeout=10)
        sensors.node.close()
