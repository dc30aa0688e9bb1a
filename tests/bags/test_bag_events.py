"""A bag written from sensor events reads back as the same events (MCAP and SQLite3, raw and PNG
images, registered and unregistered depth, 32FC1 depth, ground truth from /tf), in the same order."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader

from locnerf.bags.events import bag_events
from locnerf.bags.scenario import bag_scenario
from locnerf.bags.topics import BagTopics
from locnerf.bags.writer import BagWriter
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.frames import camera_extrinsic_opencv_to_opengl
from locnerf.geometry.se3 import interpolate_pose
from locnerf.messages.codec import decode, decode_rgbd
from locnerf.messages.schemas import Odometry, PoseStamped
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.ros2 import messages as build
from locnerf.ros2.types import CAMERA_INFO, IMAGE, ODOMETRY, TF_MESSAGE, deserialize
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf_services.sensor_ingest.service import event_message
from tests.bags.synthetic import COLOUR, random_pose, sensor_stream, write_events


def assert_same_events(read, written, depth_offset_tolerance: float = 1e-12) -> None:
    assert [type(event) for event in read] == [type(event) for event in written]
    for ours, theirs in zip(read, written, strict=True):
        assert nanoseconds_from_seconds(ours.stamp) == nanoseconds_from_seconds(theirs.stamp)
        if isinstance(theirs, ImageEvent):
            assert ours.intrinsics == theirs.intrinsics and np.array_equal(ours.pixels, theirs.pixels)
            if theirs.depth is None:
                assert ours.depth is None
                continue
            assert ours.depth.intrinsics == theirs.depth.intrinsics and np.array_equal(ours.depth.millimetres, theirs.depth.millimetres)
            if theirs.depth.T_cam_depth is None:
                assert ours.depth.T_cam_depth is None
            else:
                assert torch.allclose(ours.depth.T_cam_depth, theirs.depth.T_cam_depth, atol=depth_offset_tolerance)
        else:
            pose = "T_odom_body" if isinstance(theirs, OdometryEvent) else "T_world_cam"
            assert torch.allclose(getattr(ours, pose), getattr(theirs, pose), atol=1e-12)


@pytest.mark.parametrize(("storage", "compression", "depth"), [("mcap", "", "unregistered"), ("sqlite3", "png", "registered"), ("mcap", "", "none")])
def test_events_come_back_from_the_bag(tmp_path, storage, compression, depth):
    events = sensor_stream(seed=1, depth=depth)
    bag = write_events(tmp_path / "bag", events, storage, compression)
    topics = BagTopics(image="/camera/image_raw/compressed") if compression else None
    assert_same_events(list(bag_events(bag, topics)), events)


def test_a_32fc1_depth_image_in_metres_and_a_bgr8_image(tmp_path):
    generator = np.random.default_rng(2)
    pixels = generator.integers(0, 256, (COLOUR.height, COLOUR.width, 3), dtype=np.uint8)
    metres = generator.uniform(0.2, 4.0, (COLOUR.height, COLOUR.width)).astype(np.float32)
    metres[0, :3] = [np.nan, -1.0, np.inf]
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 5, build.odometry_message(5, torch.eye(4, dtype=torch.float64)))
        bag.write("/camera/camera_info", CAMERA_INFO, 10, build.camera_info_message(10, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 10, build.image_message(10, pixels[..., ::-1], "bgr8", "camera"))
        bag.write("/camera/depth/image_raw", IMAGE, 11, build.image_message(11, metres, "32FC1", "camera"))
    (image,) = [event for event in bag_events(tmp_path / "bag") if isinstance(event, ImageEvent)]
    assert np.array_equal(image.pixels, pixels)
    expected = np.round(metres.astype(np.float64) * 1000.0)
    expected[~np.isfinite(expected) | (expected <= 0)] = 0
    assert np.array_equal(image.depth.millimetres, expected.astype(np.uint16)) and image.depth.T_cam_depth is None


def test_ground_truth_from_tf_of_a_motion_capture_frame_moved_onto_the_camera(tmp_path):
    generator = torch.Generator().manual_seed(4)
    T_body_cam, T_world_body = random_pose(generator, 0.1), random_pose(generator)
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 0, build.odometry_message(0, torch.eye(4, dtype=torch.float64)))
        other = build.transform_stamped_message(7, "world", "table", random_pose(generator))
        mocap = build.transform_stamped_message(7, "world", "robot_body", T_world_body)
        bag.write("/tf", TF_MESSAGE, 7, build.tf_message([other, mocap]))
        bag.write("/camera/camera_info", CAMERA_INFO, 8, build.camera_info_message(8, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 8, build.image_message(8, np.zeros((12, 16, 3), np.uint8), "rgb8", "camera"))
    events = list(bag_events(tmp_path / "bag", BagTopics(ground_truth="/tf", ground_truth_frame="robot_body"), T_body_cam))
    (truth,) = [event for event in events if isinstance(event, GroundTruthEvent)]
    assert nanoseconds_from_seconds(truth.stamp) == 7 and torch.allclose(truth.T_world_cam, T_world_body @ T_body_cam, atol=1e-12)


def test_ground_truth_as_odometry_messages(tmp_path):
    T_world_body = random_pose(torch.Generator().manual_seed(5))
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 0, build.odometry_message(0, torch.eye(4, dtype=torch.float64)))
        bag.write("/mocap/odom", ODOMETRY, 3, build.odometry_message(3, T_world_body, "world", "body"))
        bag.write("/camera/camera_info", CAMERA_INFO, 8, build.camera_info_message(8, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 8, build.image_message(8, np.zeros((12, 16, 3), np.uint8), "rgb8", "camera"))
    (truth,) = [event for event in bag_events(tmp_path / "bag", BagTopics(ground_truth="mocap/odom")) if isinstance(event, GroundTruthEvent)]
    assert nanoseconds_from_seconds(truth.stamp) == 3 and torch.allclose(truth.T_world_cam, T_world_body, atol=1e-12)


def test_the_depth_offset_travels_on_tf_static_in_optical_axes(tmp_path):
    events = sensor_stream(seed=5, ticks=1)
    write_events(tmp_path / "bag", events)
    with Reader(tmp_path / "bag") as reader:
        (raw,) = [data for connection, _t, data in reader.messages() if connection.topic == "/tf_static"]
        (static,) = [connection for connection in reader.connections if connection.topic == "/tf_static"]
    assert static.ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL, "latched, as tf2's static broadcaster offers it"
    (transform,) = deserialize(bytes(raw), TF_MESSAGE).transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("camera_optical_frame", "camera_depth_optical_frame")
    offset = events[-1].depth.T_cam_depth
    opencv = camera_extrinsic_opencv_to_opengl(offset)  # its own inverse
    assert transform.transform.translation.x == pytest.approx(float(opencv[0, 3]), abs=1e-12)
    assert transform.transform.translation.y == pytest.approx(float(opencv[1, 3]), abs=1e-12)
    assert transform.transform.translation.y == pytest.approx(-float(offset[1, 3]), abs=1e-12), "y flips between OpenGL and optical axes"


def test_a_bag_as_the_offline_tracking_run(tmp_path):
    events = sensor_stream(seed=6, ticks=9, image_every=4)
    scenario = bag_scenario(write_events(tmp_path / "bag", events), MapNormalization())
    odometry = [event for event in events if isinstance(event, OdometryEvent)]
    truth = [event for event in events if isinstance(event, GroundTruthEvent)]
    assert scenario.stamps.tolist() == pytest.approx([event.stamp - odometry[0].stamp for event in odometry], abs=1e-6)
    assert torch.allclose(scenario.odometry, torch.stack([event.T_odom_body for event in odometry]), atol=1e-12)
    assert torch.allclose(scenario.truth, torch.stack([event.T_world_cam for event in truth]), atol=1e-9), "truth stamps are odometry stamps"
    assert scenario.image_ticks == [0, 4, 8]
    images = [event for event in events if isinstance(event, ImageEvent)]
    assert torch.equal(scenario.image(4, torch.Generator()), torch.from_numpy(images[1].pixels).float() / 255.0)
    depth = scenario.depth(8)
    assert torch.equal(depth.depth, torch.from_numpy(images[2].depth.millimetres.astype(np.float32)) / 1000.0)
    halfway = scenario.path.poses_at(torch.tensor([0.05], dtype=torch.float64))[0]
    assert torch.allclose(halfway, interpolate_pose(truth[0].T_world_cam, truth[1].T_world_cam, 0.5), atol=1e-5), (
        "halfway along the geodesic (float stamps near 1.7e9 s)"
    )


def test_stamps_stay_whole_nanoseconds_to_the_wire(tmp_path):
    stamp = 1_700_000_000_123_456_789  # 1.7e9 s: float seconds are 238 ns apart here
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, stamp, build.odometry_message(stamp, torch.eye(4, dtype=torch.float64)))
        bag.write("/ground_truth", "geometry_msgs/msg/PoseStamped", stamp, build.pose_stamped_message(stamp, torch.eye(4, dtype=torch.float64)))
        bag.write("/camera/camera_info", CAMERA_INFO, stamp, build.camera_info_message(stamp, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, stamp, build.image_message(stamp, np.zeros((12, 16, 3), np.uint8), "rgb8", "camera"))
    events = list(bag_events(tmp_path / "bag"))
    assert [event.stamp_ns for event in events] == [stamp] * 3
    schemas = {OdometryEvent: Odometry, GroundTruthEvent: PoseStamped}
    for event in events:
        _key, payload = event_message("r", event)
        wire = decode_rgbd(payload)[0] if isinstance(event, ImageEvent) else decode(payload, schemas[type(event)])
        assert wire.stamp_ns == stamp
