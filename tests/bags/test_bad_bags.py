"""Bad bags: a missing odometry or image topic, a topic of the wrong type, an unknown encoding, stamps
going backwards, bytes that are not CDR, a truncated file. Whole-bag problems stop before the first
event with a message naming the topic and what was expected; a bad message is counted, named and
skipped, and the replay goes on to the end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from locnerf.bags.events import bag_events
from locnerf.bags.topics import BagTopics
from locnerf.bags.writer import BagWriter
from locnerf.errors import DatasetError
from locnerf.ros2 import messages as build
from locnerf.ros2.types import CAMERA_INFO, IMAGE, ODOMETRY, POSE_STAMPED
from locnerf.sim.events import ImageEvent, OdometryEvent
from locnerf_services.runtime import load_service_config
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from tests.bags.synthetic import COLOUR, sensor_stream, write_events

EYE = torch.eye(4, dtype=torch.float64)


class Counted:
    """Bad messages by kind, with their reasons."""

    def __init__(self) -> None:
        self.reasons: dict[str, list[str]] = {}

    def __call__(self, kind: str, reason: str) -> None:
        self.reasons.setdefault(kind, []).append(reason)


def camera_bag(path, images: list[tuple[int, str]], odometry_stamps: list[int], odometry_type: str = ODOMETRY, odometry_topic: str = "/odom"):
    """Odometry stamped ``odometry_stamps`` ns (bag times 5, 15, 25, ... in that order) and (stamp ns,
    encoding) images, each after its camera info at bag time = stamp."""
    pixels = np.zeros((COLOUR.height, COLOUR.width, 3), np.uint8)
    with BagWriter(path) as bag:
        for index, stamp in enumerate(odometry_stamps):
            message = build.odometry_message(stamp, EYE) if odometry_type == ODOMETRY else build.pose_stamped_message(stamp, EYE)
            bag.write(odometry_topic, odometry_type, 5 + 10 * index, message)
        for stamp, encoding in images:
            bag.write("/camera/camera_info", CAMERA_INFO, stamp, build.camera_info_message(stamp, COLOUR, "camera"))
            bag.write("/camera/image_raw", IMAGE, stamp, build.image_message(stamp, pixels, encoding, "camera"))
    return path


def test_a_bag_without_odometry_names_the_topic_and_lists_what_it_has(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/pose", POSE_STAMPED, 1, build.pose_stamped_message(1, EYE))
        bag.write("/camera/camera_info", CAMERA_INFO, 1, build.camera_info_message(1, COLOUR, "camera"))
    with pytest.raises(DatasetError, match=r"no odometry topic /odom and it has no nav_msgs/msg/Odometry topic.*/pose \(geometry_msgs/msg/PoseStamped\)"):
        next(bag_events(tmp_path / "bag"))


def test_a_bag_without_images_names_the_image_topic(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 1, build.odometry_message(1, EYE))
    with pytest.raises(DatasetError, match=r"no image topic /camera/image_raw and it has no sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage topic"):
        next(bag_events(tmp_path / "bag"))


def test_a_topic_of_the_wrong_type_is_refused_with_both_types(tmp_path):
    camera_bag(tmp_path / "bag", [(5, "rgb8")], [1, 2], odometry_type=POSE_STAMPED)
    with pytest.raises(DatasetError, match=r"odometry topic /odom is geometry_msgs/msg/PoseStamped, expected nav_msgs/msg/Odometry"):
        next(bag_events(tmp_path / "bag"))


def test_a_single_odometry_topic_under_another_name_is_taken(tmp_path):
    camera_bag(tmp_path / "bag", [(10, "rgb8")], [5, 15], odometry_topic="/vio/odometry")
    stamps = [round(event.stamp * 1e9) for event in bag_events(tmp_path / "bag") if isinstance(event, OdometryEvent)]
    assert stamps == [5, 15]


def test_an_unknown_encoding_in_the_middle_is_counted_and_skipped(tmp_path):
    camera_bag(tmp_path / "bag", [(10, "rgb8"), (20, "bayer_rggb8"), (30, "rgb8")], [5, 15, 25, 35])
    counted = Counted()
    events = list(bag_events(tmp_path / "bag", record=counted))
    assert [round(event.stamp * 1e9) for event in events if isinstance(event, ImageEvent)] == [10, 30]
    assert sum(isinstance(event, OdometryEvent) for event in events) == 4, "the replay went on to the end"
    (reason,) = counted.reasons["ros2_encoding"]
    assert reason.startswith("/camera/image_raw: ") and "'bayer_rggb8'" in reason and "rgb8" in reason


def test_stamps_going_backwards_are_counted_and_skipped(tmp_path):
    camera_bag(tmp_path / "bag", [(10, "rgb8")], [5, 15, 12, 25])  # stamped 12 ns, recorded after the one of 15 ns
    counted = Counted()
    stamps = [round(event.stamp * 1e9) for event in bag_events(tmp_path / "bag", record=counted) if isinstance(event, OdometryEvent)]
    assert stamps == [5, 15, 25]
    (reason,) = counted.reasons["bag_stamp_backwards"]
    assert reason.startswith("/odom: stamp 12 ns after 15 ns")


def test_bytes_that_are_not_cdr_are_counted_and_skipped(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 1, build.odometry_message(1, EYE))
        bag.write_cdr("/odom", ODOMETRY, 2, b"\x00\x01\x00\x00garbage")
        bag.write("/odom", ODOMETRY, 3, build.odometry_message(3, EYE))
        bag.write("/camera/camera_info", CAMERA_INFO, 4, build.camera_info_message(4, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 4, build.image_message(4, np.zeros((COLOUR.height, COLOUR.width, 3), np.uint8), "rgb8", "camera"))
    counted = Counted()
    assert len(list(bag_events(tmp_path / "bag", record=counted))) == 3
    assert len(counted.reasons["ros2_cdr"]) == 1 and counted.reasons["ros2_cdr"][0].startswith("/odom: ")


def test_an_image_before_its_camera_info_is_counted(tmp_path):
    pixels = np.zeros((COLOUR.height, COLOUR.width, 3), np.uint8)
    with BagWriter(tmp_path / "bag") as bag:
        bag.write("/odom", ODOMETRY, 1, build.odometry_message(1, EYE))
        bag.write("/camera/image_raw", IMAGE, 2, build.image_message(2, pixels, "rgb8", "camera"))
        bag.write("/camera/camera_info", CAMERA_INFO, 3, build.camera_info_message(3, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 4, build.image_message(4, pixels, "rgb8", "camera"))
    counted = Counted()
    images = [event for event in bag_events(tmp_path / "bag", record=counted) if isinstance(event, ImageEvent)]
    assert len(images) == 1 and "/camera/camera_info" in counted.reasons["ros2_no_camera_info"][0]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_truncated_bag_is_refused_with_the_bag_named(tmp_path, storage):
    bag = write_events(tmp_path / "bag", sensor_stream(seed=7), storage)
    (data,) = [file for file in bag.iterdir() if file.suffix in (".mcap", ".db3")]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    with pytest.raises(DatasetError, match=rf"bag {bag}: cannot be opened .*expected a complete rosbag2"):
        next(bag_events(bag))


def test_a_missing_bag_and_a_folder_that_is_no_bag(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file or folder"):
        next(bag_events(tmp_path / "absent"))
    (tmp_path / "folder").mkdir()
    with pytest.raises(DatasetError, match=r"bag .*folder"):
        next(bag_events(tmp_path / "folder"))


def test_ground_truth_on_tf_needs_the_frame(tmp_path):
    with BagWriter(tmp_path / "tf") as bag:
        bag.write("/odom", ODOMETRY, 1, build.odometry_message(1, EYE))
        bag.write("/camera/camera_info", CAMERA_INFO, 1, build.camera_info_message(1, COLOUR, "camera"))
        bag.write("/camera/image_raw", IMAGE, 1, build.image_message(1, np.zeros((COLOUR.height, COLOUR.width, 3), np.uint8), "rgb8", "camera"))
        bag.write("/tf", "tf2_msgs/msg/TFMessage", 1, build.tf_message([build.transform_stamped_message(1, "world", "body", EYE)]))
    with pytest.raises(DatasetError, match=r"ground truth from /tf needs ground_truth_frame"):
        next(bag_events(tmp_path / "tf", BagTopics(ground_truth="/tf")))


def test_the_example_ingest_configuration_loads_and_names_its_bag():
    config = load_service_config(IngestConfig, Path(__file__).resolve().parents[2] / "deploy/config/ingest_rosbag.toml", {})
    assert config.source == "rosbag" and config.rosbag.topics == BagTopics()
    with pytest.raises(FileNotFoundError, match="bag /data/bags/run: no such file or folder"):
        next(sensor_events(config))
