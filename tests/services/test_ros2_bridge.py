"""The filter's ROS 2 bridge on the in-memory bus: frames, outputs, the service, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import SearchRegion
from locnerf.geometry.se3 import make_pose
from locnerf.geometry.so3 import so3_exp
from locnerf.messages import keys
from locnerf.messages.codec import decode
from locnerf.messages.schemas import PoseEstimate
from locnerf.ros2 import convert
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import data_key
from locnerf.ros2.types import (
    dds_type_name,
    deserialize,
    message_class,
    serialize,
    type_hash,
)
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.driver import FilterDriver
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.filter_bridge import FilterRos2Bridge
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.transport.memory import MemoryBus
from tests.ros2 import messages

ROBOT = "r"


def pose(rotvec, translation) -> torch.Tensor:
    return make_pose(so3_exp(torch.tensor(rotvec, dtype=torch.float64)), torch.tensor(translation, dtype=torch.float64))


T_BODY_CAM = pose([0.0, 0.3, 0.0], [0.1, 0.0, 0.2])


def setup():
    world = ProceduralWorld.default()
    bounds = world.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
    localizer = Localizer(preset("llff").model_copy(update={"particles": 20}), torch.Generator().manual_seed(0), region=region)
    config = FilterLoopConfig(start="wait", T_body_cam=T_BODY_CAM.tolist())
    loop = FilterLoop(ROBOT, localizer, world.normalization, region, config, lambda: 0.0, world.checksum)
    bus = MemoryBus()
    received: dict[str, list] = {"pose": [], "cloud": [], "legacy": [], "tf": [], "locnerf": []}
    bus.subscribe(keys.key(ROBOT, keys.POSE), lambda _k, payload: received["locnerf"].append(payload))
    types = {
        "pose": ("amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
        "cloud": ("particle_cloud", "nav2_msgs/msg/ParticleCloud"),
        "legacy": ("particlecloud", "geometry_msgs/msg/PoseArray"),
        "tf": ("tf", "tf2_msgs/msg/TFMessage"),
    }
    for name, (topic, ros_type) in types.items():
        bus.subscribe_attached(
            data_key(0, "/" + topic, ros_type),
            lambda _k, payload, att, name=name, ros_type=ros_type: received[name].append((deserialize(payload, ros_type), Attachment.decode(att))),
        )
    driver = FilterDriver(loop, bus, clock=lambda: 0.0, ros2=FilterRos2Bridge(loop, bus, Ros2Config(enabled=True, legacy_particles_topic="particlecloud")))
    driver.subscribe()
    vio = Ros2Node(bus, 0, "vio")
    publishers = {
        "odom": vio.publisher("odom", "nav_msgs/msg/Odometry"),
        "initialpose": vio.publisher("initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
        "image": vio.publisher("camera/image_raw", "sensor_msgs/msg/Image"),
        "info": vio.publisher("camera/camera_info", "sensor_msgs/msg/CameraInfo"),
    }
    return world, loop, bus, driver, publishers, received


def drain(driver, steps: int = 6) -> None:
    for _ in range(steps):
        driver.step(timeout=0.0)


def test_initial_pose_odometry_and_outputs_follow_the_amcl_frames():
    _, loop, _, driver, publishers, received = setup()
    T_map_base = pose([0.0, 0.0, 0.5], [0.3, -0.2, 0.1])
    covariance = np.diag([1e-8, 1e-8, 1e-8, 1e-10, 1e-10, 1e-10]).reshape(-1).tolist()
    publishers["initialpose"].publish(messages.initial_pose(10.0, T_map_base, covariance))
    drain(driver)  # the command first: queued odometry would be served before it
    T_odom_base = pose([0.0, 0.0, -0.2], [1.0, 2.0, 0.0])
    publishers["odom"].publish(messages.odometry(10.0, T_odom_base))
    drain(driver)
    assert loop.running and loop.bad.total == 0
    # The filter moves the camera: its odometry pose is the body's carried by T_body_cam.
    assert torch.allclose(loop.history.latest_pose, T_odom_base @ T_BODY_CAM, atol=1e-12)
    message, attachment = received["pose"][-1]
    assert message.header.frame_id == "map" and convert.seconds(message.header.stamp) == 10.0 and attachment.sequence_number == 1
    published = convert.pose_from_message(message.pose.pose)
    assert torch.allclose(published, T_map_base, atol=1e-3), "amcl_pose is the base pose given in initialpose"
    # The filter holds the camera: T_map_cam = T_map_base · T_body_cam.
    camera = decode(received["locnerf"][-1], PoseEstimate)
    assert torch.allclose(torch.tensor(camera.T_world_cam, dtype=torch.float64), T_map_base @ T_BODY_CAM, atol=1e-3)
    transform = received["tf"][-1][0].transforms[0]
    assert (transform.header.frame_id, transform.child_frame_id) == ("map", "odom")
    assert convert.seconds(transform.header.stamp) == 11.0, "future-dated by transform_tolerance (nav2_amcl's 1 s)"
    t, q = transform.transform.translation, transform.transform.rotation
    rosless = message_class("geometry_msgs/msg/Pose")(position=message_class("geometry_msgs/msg/Point")(t.x, t.y, t.z), orientation=q)
    T_map_odom = convert.pose_from_message(rosless)
    assert torch.allclose(T_map_odom @ T_odom_base, published, atol=1e-9), "T_map_odom = T_map_base · T_odom_base⁻¹"
    assert len(message.pose.covariance) == 36
    # The particle cloud (nav2_msgs/ParticleCloud): one base pose and its weight per particle, all near
    # the initial pose (the llff prediction noise has σ = 0.01 m per step: 0.1 m is 10 σ); the same
    # poses as a PoseArray on the legacy topic.
    loop._last_particles = -math.inf
    drain(driver, 2)
    cloud = received["cloud"][-1][0]
    assert len(cloud.particles) == loop.localizer.particles.poses.shape[0] and cloud.header.frame_id == "map"
    assert max(abs(p.pose.position.x - T_map_base[0, 3].item()) for p in cloud.particles) < 0.1
    weights = [p.weight for p in cloud.particles]
    assert weights == pytest.approx(loop.localizer.particles.weights.tolist()) and sum(weights) == pytest.approx(1.0)
    legacy = received["legacy"][-1][0]
    assert [p.position.x for p in legacy.poses] == [p.pose.position.x for p in cloud.particles] and legacy.header == cloud.header


def test_the_service_reinitialises_and_replies_with_the_request_sequence_and_gid():
    _, loop, bus, driver, publishers, _ = setup()
    publishers["odom"].publish(messages.odometry(1.0, torch.eye(4, dtype=torch.float64)))
    drain(driver)
    request = serialize(message_class("std_srvs/srv/Empty_Request")(), "std_srvs/srv/Empty_Request")
    key = f"0/reinitialize_global_localization/{dds_type_name('std_srvs/srv/Empty')}/{type_hash('std_srvs/srv/Empty')}"
    asked = Attachment(42, 123, bytes(range(16)))
    replies = bus.query(key, request, attachment=asked.encode())
    assert len(replies) == 1
    reply_key, payload, attachment = replies[0]
    answer = Attachment.decode(attachment)
    assert reply_key == key and payload == b"\x00\x01\x00\x00\x00" and (answer.sequence_number, answer.gid) == (42, asked.gid)
    epoch = loop.localizer.epoch
    drain(driver)
    assert loop.running and loop.localizer.epoch == epoch + 1
    # A request on another type hash: no reply, counted, no re-initialisation.
    assert bus.query(key.rsplit("/", 1)[0] + "/RIHS01_" + "1" * 64, request, attachment=asked.encode()) == []
    drain(driver)
    assert loop.localizer.epoch == epoch + 1 and loop.counters()["bad_ros2_type_hash"] == 1


def test_bad_ros_input_is_counted_and_dropped_and_the_filter_keeps_publishing():
    world, loop, bus, driver, publishers, received = setup()
    good = publishers["odom"]
    good.publish(messages.odometry(1.0, torch.eye(4, dtype=torch.float64)))
    wrong_hash = good.key.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
    valid = Attachment(1, 0, bytes(16)).encode()
    bus.publish(good.key, b"\x00\x01\x00\x00garbage", valid)  # malformed CDR
    bus.publish(wrong_hash, serialize(messages.odometry(1.1, torch.eye(4, dtype=torch.float64)), "nav_msgs/msg/Odometry"), valid)
    bus.publish(good.key, serialize(messages.odometry(1.2, torch.eye(4, dtype=torch.float64)), "nav_msgs/msg/Odometry"))  # no attachment
    publishers["odom"].publish(messages.odometry(1.25, torch.eye(4, dtype=torch.float64), base_frame="imu_link"))
    intrinsics = world.default_intrinsics
    frame = np.zeros((intrinsics.height, intrinsics.width, 3), np.uint8)
    publishers["image"].publish(messages.image(1.0, frame))  # before any camera info
    publishers["info"].publish(messages.camera_info(1.0, intrinsics))
    drain(driver)
    odd = messages.image(1.0, frame)
    odd.encoding = "yuv422"
    publishers["image"].publish(odd)
    drain(driver)
    counts = driver.loop.counters()
    for kind in ("ros2_cdr", "ros2_type_hash", "ros2_attachment", "ros2_frame", "ros2_no_camera_info", "ros2_encoding"):
        assert counts[f"bad_{kind}"] == 1, (kind, counts)
    publishers["initialpose"].publish(messages.initial_pose(1.3, torch.eye(4, dtype=torch.float64), np.eye(6).reshape(-1).tolist()))
    drain(driver)
    good.publish(messages.odometry(1.4, torch.eye(4, dtype=torch.float64)))
    drain(driver)
    assert loop.running and convert.seconds(received["pose"][-1][0].header.stamp) == 1.4
    assert loop.counters()["bad_messages"] == 6
    publishers["image"].publish(messages.image(1.4, frame))
    driver._take_image()
    assert loop._image is not None and loop.counters()["bad_messages"] == 6, "a good image after the bad ones is kept"


def test_t_body_cam_must_be_a_rigid_transform():
    with pytest.raises(ValueError, match="T_body_cam"):
        FilterLoopConfig(T_body_cam=(2 * torch.eye(4, dtype=torch.float64)).tolist())
    with pytest.raises(ValueError, match="4×4"):
        FilterLoopConfig(T_body_cam=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def test_a_ros_stamp_comes_back_in_amcl_pose_tf_and_the_particle_cloud_to_the_nanosecond():
    world, loop, _, driver, publishers, received = setup()
    exact = 1_700_000_000_123_456_789  # through float seconds it would come back as ...123_456_717
    initial = messages.initial_pose(0.0, torch.eye(4, dtype=torch.float64), (1e-4 * np.eye(6)).reshape(-1).tolist())
    initial.header.stamp = convert.time_message(exact)
    publishers["initialpose"].publish(initial)
    drain(driver)
    intrinsics = world.default_intrinsics
    sensors = [messages.odometry(0.0, torch.eye(4, dtype=torch.float64)), messages.camera_info(0.0, intrinsics)]
    sensors.append(messages.image(0.0, np.zeros((intrinsics.height, intrinsics.width, 3), np.uint8)))
    for message in sensors:
        message.header.stamp = convert.time_message(exact)
    for name, message in zip(("odom", "info", "image"), sensors, strict=True):
        publishers[name].publish(message)
        drain(driver)  # the camera info before the image
    loop._last_particles = -math.inf
    drain(driver)
    assert loop.running and loop.bad.total == 0
    pose_stamp = received["pose"][-1][0].header.stamp
    assert (pose_stamp.sec, pose_stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert convert.nanoseconds(received["tf"][-1][0].transforms[0].header.stamp) == exact + 1_000_000_000  # transform_tolerance 1 s
    assert convert.nanoseconds(received["cloud"][-1][0].header.stamp) == exact
    assert decode(received["locnerf"][-1], PoseEstimate).stamp_ns == exact
    assert loop._image[0].stamp_ns == exact, "the image's stamp reaches the filter exactly"
