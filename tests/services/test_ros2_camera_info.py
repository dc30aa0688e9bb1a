"""Camera info on the ROS 2 sensor path (the ingest's ros2 source on the in-memory bus; the filter's
bridge uses the same translation): a bad or unsupported CameraInfo is counted and dropped before any
image meets OpenCV, a rectified topic is taken as it is with P, a binned image takes binned intrinsics."""

from __future__ import annotations

import numpy as np
import pytest

from locnerf.messages import keys
from locnerf.messages.codec import decode_image
from locnerf.render.camera import PinholeIntrinsics
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.sensor_ingest.ros2_source import Ros2Ingest
from locnerf_services.transport.memory import MemoryBus
from tests.ros2 import messages

ROBOT = "r"
SENSOR = PinholeIntrinsics(fx=20.0, fy=21.0, cx=8.0, cy=6.0, width=16, height=12)
PIXELS = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)


def rig(config: Ros2Config) -> tuple[Ros2Ingest, dict[str, object], list[bytes]]:
    """The ingest reading ``config``'s topics, a camera driver's publishers and the frames sent."""
    bus = MemoryBus()
    frames: list[bytes] = []
    bus.subscribe(keys.key(ROBOT, keys.IMAGE), lambda _key, payload: frames.append(payload))
    driver = Ros2Node(bus, 0, "camera")
    publishers = {
        "image": driver.publisher("/" + config.image_topic, "sensor_msgs/msg/Image"),
        "info": driver.publisher("/" + config.camera_info_topic, "sensor_msgs/msg/CameraInfo"),
    }
    return Ros2Ingest(bus, ROBOT, config), publishers, frames


def send(ingest: Ros2Ingest, publishers: dict[str, object], info: object, pixels: np.ndarray, stamp: float) -> None:
    publishers["info"].publish(info)
    publishers["image"].publish(messages.image(stamp, pixels))
    for _ in range(3):
        ingest.step(timeout=0.0)


@pytest.mark.parametrize(
    ("model", "coefficients", "kind"),
    [("plumb_bob", 3, "ros2_camera_info"), ("rational_polynomial", 5, "ros2_camera_info"), ("fov", 1, "ros2_camera_info_unsupported")],
)
def test_a_bad_camera_info_is_counted_and_the_images_go_on(model, coefficients, kind):
    """D of a length OpenCV refuses made cv2.undistort raise in the ingest on the next image."""
    ingest, publishers, frames = rig(Ros2Config())
    bad = messages.camera_info(1.0, SENSOR, distortion=np.full(coefficients, 0.01))
    bad.distortion_model = model
    send(ingest, publishers, bad, PIXELS, 1.0)
    assert frames == [] and dict(ingest.bad.counts) == {kind: 1, "ros2_no_camera_info": 1}
    send(ingest, publishers, messages.camera_info(2.0, SENSOR), PIXELS, 2.0)
    send(ingest, publishers, bad, PIXELS, 3.0)
    assert ingest.bad.counts[kind] == 2 and len(frames) == 2, "a bad camera info leaves the previous camera in place"
    assert all(np.array_equal(decode_image(frame)[1], PIXELS) for frame in frames)
    ingest.close()


def test_a_rectified_topic_is_taken_as_it_is_with_the_intrinsics_of_p():
    """image_proc's image_rect comes with the raw camera's CameraInfo: non-zero D, and P for the rectified image."""
    config = Ros2Config(image_topic="camera/image_rect", camera_info_topic="camera/camera_info")
    assert config.images_rectified and not Ros2Config().images_rectified and not Ros2Config(image_topic="a/image_rect", image_rectified=False).images_rectified
    ingest, publishers, frames = rig(config)
    info = messages.camera_info(1.0, SENSOR, distortion=np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))
    info.p = np.array([18.0, 0.0, 7.5, 0.0, 0.0, 18.5, 5.5, 0.0, 0.0, 0.0, 1.0, 0.0])
    send(ingest, publishers, info, PIXELS, 1.0)
    header, rgb = decode_image(frames[0])
    assert np.array_equal(rgb, PIXELS), "not undistorted a second time"
    assert header.intrinsics == PinholeIntrinsics(fx=18.0, fy=18.5, cx=7.5, cy=5.5, width=16, height=12)
    ingest.close()


def test_a_binned_image_takes_the_binned_intrinsics():
    """The CameraInfo describes the full 32×24 sensor; with binning 2 the images are 16×12."""
    ingest, publishers, frames = rig(Ros2Config())
    full = PinholeIntrinsics(fx=40.0, fy=42.0, cx=16.0, cy=12.0, width=32, height=24)
    info = messages.camera_info(1.0, full)
    info.binning_x = info.binning_y = 2
    send(ingest, publishers, info, PIXELS, 1.0)
    binned = PinholeIntrinsics(fx=20.0, fy=21.0, cx=7.75, cy=5.75, width=16, height=12)  # (c + 0.5) / 2 - 0.5: pixel centres at integers
    assert ingest.bad.total == 0 and decode_image(frames[0])[0].intrinsics == binned
    ingest.close()
