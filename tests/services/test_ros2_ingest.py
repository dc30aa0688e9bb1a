"""The ingest's ros2 source on the in-memory bus: ROS 2 sensor topics republished as locnerf messages."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from locnerf.geometry.se3 import make_pose
from locnerf.geometry.so3 import so3_exp
from locnerf.messages import keys
from locnerf.messages.codec import decode, decode_image
from locnerf.messages.schemas import Odometry
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2.attachment import Attachment
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from locnerf_services.sensor_ingest.ros2_source import Ros2Ingest
from locnerf_services.transport.memory import MemoryBus
from tests.ros2 import messages

ROBOT = "r"


def test_ros2_topics_are_republished_on_the_sensor_keys_and_bad_samples_counted():
    bus = MemoryBus()
    out: dict[str, list[bytes]] = {"odom": [], "image": []}
    bus.subscribe(keys.key(ROBOT, keys.ODOMETRY), lambda _k, payload: out["odom"].append(payload))
    bus.subscribe(keys.key(ROBOT, keys.IMAGE), lambda _k, payload: out["image"].append(payload))
    ingest = Ros2Ingest(bus, ROBOT, Ros2Config())
    assert any(token.endswith("/NN/%/%/locnerf_ingest") for token in ingest.node.tokens)
    vio = Ros2Node(bus, 0, "vio")
    odom = vio.publisher("odom", "nav_msgs/msg/Odometry")
    image = vio.publisher("camera/image_raw", "sensor_msgs/msg/Image")
    info = vio.publisher("camera/camera_info", "sensor_msgs/msg/CameraInfo")
    pose = make_pose(so3_exp(torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    intrinsics = PinholeIntrinsics(fx=20.0, fy=20.0, cx=4.0, cy=3.0, width=8, height=6)
    pixels = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)

    odom.publish(messages.odometry(5.5, pose))
    info.publish(messages.camera_info(5.5, intrinsics))
    image.publish(messages.image(5.5, pixels, encoding="bgr8"))
    bus.publish(odom.key, b"\x00\x01\x00\x00 not an odometry", Attachment(1, 0, bytes(16)).encode())
    for _ in range(4):
        ingest.step(timeout=0.0)

    odometry = decode(out["odom"][0], Odometry)
    assert odometry.stamp == pytest.approx(5.5) and odometry.frame_id == "odom"
    torch.testing.assert_close(torch.tensor(odometry.T_odom_body, dtype=torch.float64), pose, atol=1e-12, rtol=0)
    header, rgb = decode_image(out["image"][0])
    assert np.array_equal(rgb, pixels) and header.intrinsics == intrinsics and header.stamp == pytest.approx(5.5)
    assert ingest.sent == 2 and dict(ingest.bad.counts) == {"ros2_cdr": 1}
    ingest.close()


def test_the_ros2_source_has_no_event_stream():
    with pytest.raises(ValueError, match="relays the ROS 2 topics"):
        sensor_events(IngestConfig(source="ros2"))
