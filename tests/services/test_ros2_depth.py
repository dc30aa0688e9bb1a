"""Depth images from ROS 2 on the in-memory bus: paired with their colour image by stamp into one
RGB-D frame, by the ingest's ros2 source and by the filter's bridge; bad depth counted, colour kept."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import SearchRegion
from locnerf.messages import keys
from locnerf.messages.codec import decode_rgbd
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2.camera_info import rectification_from_camera_info
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.driver import FilterDriver
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.filter_bridge import FilterRos2Bridge
from locnerf_services.sensor_ingest.ros2_source import Ros2Ingest
from locnerf_services.transport.memory import MemoryBus
from tests.ros2 import messages
from tests.ros2.rgbd_camera import RgbdCamera, rgbd_config

ROBOT = "r"
COLOUR = PinholeIntrinsics(fx=20.0, fy=21.0, cx=16.0, cy=12.0, width=32, height=24)
DEPTH = PinholeIntrinsics(fx=10.0, fy=10.0, cx=2.0, cy=1.5, width=4, height=3)


class Clock:
    """Monotonic seconds that move only when told to."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def ingest_rig(config: Ros2Config) -> tuple[Ros2Ingest, RgbdCamera, list[bytes], Clock]:
    bus, clock = MemoryBus(), Clock()
    frames: list[bytes] = []
    bus.subscribe(keys.key(ROBOT, keys.IMAGE), lambda _key, payload: frames.append(payload))
    return Ros2Ingest(bus, ROBOT, config, clock=clock), RgbdCamera(bus, config), frames, clock


def steps(ingest: Ros2Ingest, count: int = 3) -> None:
    for _ in range(count):
        ingest.step(timeout=0.0)


def test_a_registered_depth_image_arriving_after_its_colour_image_joins_it_in_one_frame():
    """The aligned depth has the colour camera's intrinsics and distortion: both are undistorted alike."""
    generator = np.random.default_rng(0)
    pixels = generator.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    millimetres = generator.integers(1, 8000, (24, 32), dtype=np.uint16)
    distortion = np.array([-0.1, 0.01, 0.0, 0.0, 0.0])
    ingest, camera, frames, clock = ingest_rig(rgbd_config(depth_max_wait=0.1))
    camera.infos(5.5, COLOUR, distortion=distortion)
    camera.colour_image(5.5, pixels)
    steps(ingest)
    assert frames == [] and ingest.sensors.pairing.time_left() == pytest.approx(0.1), "the colour image waits for its depth"
    clock.now += 0.01
    camera.depth_image(5.504, millimetres)
    steps(ingest, 1)
    header, rgb, depth = decode_rgbd(frames[0])
    camera = rectification_from_camera_info(messages.camera_info(5.5, COLOUR, distortion=distortion))
    assert header.stamp == pytest.approx(5.5) and header.intrinsics == COLOUR and np.array_equal(rgb, camera.colour(pixels))
    assert header.depth is not None and header.depth.intrinsics == COLOUR and header.depth.T_cam_depth is None
    assert np.array_equal(depth, camera.depth(millimetres)) and not np.array_equal(depth, millimetres)
    assert ingest.counters() == {"events_sent": 1, "images_replaced": 0, "images_without_depth": 0} and ingest.bad.total == 0


def test_unregistered_depth_takes_its_own_camera_and_the_extrinsic_in_opengl_axes():
    """By hand: the depth camera 5 cm right, 1 cm down and 2 mm ahead of the colour camera, turned
    90° about the optical axis (ROS axes), is 1 cm up and 2 mm behind in OpenGL axes, turned -90°
    about OpenGL's z (which points backwards)."""
    T_colour_depth = [[0.0, -1.0, 0.0, 0.05], [1.0, 0.0, 0.0, 0.01], [0.0, 0.0, 1.0, 0.002], [0.0, 0.0, 0.0, 1.0]]
    ingest, camera, frames, _ = ingest_rig(rgbd_config(registered=False, T_colour_depth=T_colour_depth))
    metres = np.array([[1.0, 2.5, np.nan, 0.0], [70.0, -1.0, 0.1234, 3.0], [4.0, 4.0, 4.0, np.inf]], dtype=np.float32)
    camera.infos(1.0, COLOUR, DEPTH)
    camera.depth_image(1.0, metres, "32FC1")
    camera.colour_image(1.0, np.zeros((24, 32, 3), np.uint8))
    steps(ingest)
    header, _, depth = decode_rgbd(frames[0])
    assert header.depth is not None and header.depth.intrinsics == DEPTH
    assert np.array_equal(depth, [[1000, 2500, 0, 0], [0, 0, 123, 3000], [4000, 4000, 4000, 0]])
    expected = [[0.0, 1.0, 0.0, 0.05], [-1.0, 0.0, 0.0, -0.01], [0.0, 0.0, 1.0, -0.002], [0.0, 0.0, 0.0, 1.0]]
    assert np.allclose(header.depth.T_cam_depth, expected, atol=1e-15)


def test_bad_depth_images_are_counted_and_the_colour_image_goes_alone_after_the_wait():
    ingest, camera, frames, clock = ingest_rig(rgbd_config(depth_max_wait=0.1))
    pixels = np.zeros((24, 32, 3), np.uint8)
    camera.depth_image(0.9, np.ones((24, 32), np.uint16))  # before any camera info
    camera.infos(1.0, COLOUR)
    camera.colour_image(1.0, pixels)
    camera.depth_image(1.0, np.ones((3, 4), np.uint16))  # not the colour image's size
    odd = messages.depth_image(1.0, np.ones((24, 32), np.uint16))
    odd.encoding = "8UC1"
    camera.depth.publish(odd)
    steps(ingest)
    assert frames == [] and dict(ingest.bad.counts) == {"ros2_no_camera_info": 1, "ros2_depth_size": 1, "ros2_depth_encoding": 1}
    clock.now += 0.1
    steps(ingest, 1)
    header, _, depth = decode_rgbd(frames.pop())
    assert header.depth is None and depth is None and ingest.counters()["images_without_depth"] == 1
    camera.colour_image(2.0, pixels)
    camera.depth_image(2.0, np.full((24, 32), 1500, np.uint16), "mono16")
    steps(ingest)
    _, _, depth = decode_rgbd(frames.pop())
    assert depth is not None and (depth == 1500).all(), "the stream goes on"
    assert ingest.bad.total == 3 and ingest.counters()["images_without_depth"] == 1


def filter_rig(config: Ros2Config, clock: Clock) -> tuple[FilterLoop, FilterDriver, RgbdCamera]:
    world = ProceduralWorld.default()
    bounds = world.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
    localizer = Localizer(preset("llff").model_copy(update={"particles": 20}), torch.Generator().manual_seed(0), region=region)
    loop = FilterLoop(ROBOT, localizer, world.normalization, region, FilterLoopConfig(start="wait"), clock, world.checksum)
    bus = MemoryBus()
    driver = FilterDriver(loop, bus, clock=clock, ros2=FilterRos2Bridge(loop, bus, config, clock))
    driver.subscribe()
    return loop, driver, RgbdCamera(bus, config)


def test_the_filter_pairs_a_depth_image_in_the_turn_that_handles_its_arrival():
    """The driver's schedule: a turn takes one arrival, then the newest image. The colour image waits
    in the bridge; the turn that takes the late depth image's arrival completes the pair."""
    clock = Clock()
    loop, driver, camera = filter_rig(rgbd_config(enabled=True, depth_max_wait=0.1), clock)
    millimetres = np.random.default_rng(1).integers(1, 8000, (24, 32), dtype=np.uint16)
    camera.infos(3.0, COLOUR)
    camera.colour_image(3.0, np.zeros((24, 32, 3), np.uint8))
    for _ in range(3):
        driver.step(timeout=0.0)
    assert loop._image is None and driver.inbox.waiting(1) == 0
    camera.depth_image(3.0, millimetres)
    driver.step(timeout=0.0)
    header, _, depth = loop._image
    assert header.depth is not None and np.array_equal(depth, millimetres) and header.depth.intrinsics == COLOUR
    # No depth image: the colour image goes alone once the wait is over, counted in the status.
    camera.colour_image(3.5, np.zeros((24, 32, 3), np.uint8))
    driver.step(timeout=0.0)
    assert loop._image[0].stamp == 3.0
    clock.now += 0.1
    driver.step(timeout=0.0)
    header, _, depth = loop._image
    assert header.stamp == 3.5 and depth is None
    counters = loop.counters()
    assert counters["images_without_depth"] == 1 and counters["bad_messages"] == 0 and counters["images_received"] == 2


def test_depth_settings_are_checked():
    with pytest.raises(ValueError, match="depth_camera_info_topic"):
        Ros2Config(depth_topic="d", T_colour_depth=np.eye(4).tolist())
    turned = np.eye(4)
    turned[:3, :3] *= 2.0
    with pytest.raises(ValueError, match="T_colour_depth"):
        Ros2Config(depth_topic="d", depth_camera_info_topic="i", T_colour_depth=turned.tolist())
    with pytest.raises(ValueError, match="T_colour_depth"):
        Ros2Config(depth_topic="d", depth_camera_info_topic="i", T_colour_depth=[[math.nan] * 4] * 4)
    with pytest.raises(ValueError, match="depth_pairing_tolerance"):
        Ros2Config(depth_pairing_tolerance=-0.01)
