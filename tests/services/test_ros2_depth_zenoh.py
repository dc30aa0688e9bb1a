"""Depth from ROS 2 over real Zenoh on loopback (peer mode, multicast scouting off, explicit
tcp/127.0.0.1 endpoints): a RealSense-like driver publishes colour, aligned depth and camera info
(rosbags CDR, rmw_zenoh keys and attachments) to the ingest's ros2 source and to a filter whose
bridge reads the topics, at once. The depth image is published only once its colour image waits in
both, as a real aligned depth comes after its colour image; both deliver one RGB-D frame, a bad
depth image is counted by both, and the stream goes on."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import SearchRegion
from locnerf.messages import keys
from locnerf.messages.codec import decode_rgbd
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.driver import FilterDriver
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.ros2.filter_bridge import FilterRos2Bridge
from locnerf_services.sensor_ingest.ros2_source import Ros2Ingest
from locnerf_services.transport import Bus, Inbox, TransportConfig, open_bus
from tests.ros2 import messages
from tests.ros2.rgbd_camera import RgbdCamera, rgbd_config
from tests.services.helpers import free_port

FILTER_ROBOT, INGEST_ROBOT = "f", "i"  # apart: the filter must not also read the ingest's sensors/image
COLOUR = PinholeIntrinsics(fx=30.0, fy=30.0, cx=16.0, cy=12.0, width=32, height=24)
CONFIG = rgbd_config(enabled=True, depth_pairing_tolerance=0.02, depth_max_wait=60.0)  # the depth is awaited, never given up on
TIMEOUT = 20.0


@pytest.fixture
def buses() -> Iterator[dict[str, Bus]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    opened = {"hub": open_bus(TransportConfig(listen=(endpoint,)))}
    try:
        for name in ("camera", "ingest", "filter", "observer"):
            opened[name] = open_bus(TransportConfig(connect=(endpoint,)))
        yield opened
    finally:
        for bus in reversed(opened.values()):
            bus.close()


def filter_driver(bus: Bus) -> tuple[FilterLoop, FilterDriver]:
    world = ProceduralWorld.default()
    bounds = world.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
    localizer = Localizer(preset("llff").model_copy(update={"particles": 20}), torch.Generator().manual_seed(0), region=region)
    loop = FilterLoop(FILTER_ROBOT, localizer, world.normalization, region, FilterLoopConfig(start="wait"), time.monotonic, world.checksum)
    driver = FilterDriver(loop, bus, ros2=FilterRos2Bridge(loop, bus, CONFIG))
    driver.subscribe()
    return loop, driver


def test_depth_reaches_the_ingest_and_the_filter_as_one_rgbd_frame(buses):
    ingest = Ros2Ingest(buses["ingest"], INGEST_ROBOT, CONFIG)
    loop, driver = filter_driver(buses["filter"])
    relayed: Inbox[bytes] = Inbox()
    buses["observer"].subscribe(keys.key(INGEST_ROBOT, keys.IMAGE), lambda _key, payload: relayed.put(payload))
    camera = RgbdCamera(buses["camera"], CONFIG)
    bridge_pairing, ingest_pairing = driver.ros2.sensors.pairing, ingest.sensors.pairing

    def until(condition: Callable[[], bool], what: str, publish: Callable[[], None] = lambda: None) -> None:
        """Publish (again: Zenoh routes are declared asynchronously) and run both consumers until ``condition``."""
        deadline = time.monotonic() + TIMEOUT
        while not condition():
            assert time.monotonic() < deadline, f"timed out after {TIMEOUT} s waiting for {what}"
            publish()
            for _ in range(5):
                ingest.step(timeout=0.002)
                driver.step(timeout=0.002)

    generator = np.random.default_rng(3)
    for frame, stamp in enumerate((1_700_000_000.0, 1_700_000_001.0)):
        pixels = generator.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        millimetres = generator.integers(1, 10_000, (24, 32), dtype=np.uint16)
        until(
            lambda: ingest_pairing.time_left() is not None and bridge_pairing.time_left() is not None,
            f"colour image {frame} to wait in both",
            lambda: (camera.infos(stamp, COLOUR), camera.colour_image(stamp, pixels)),
        )
        previous = bridge_pairing.paired
        until(
            lambda: ingest_pairing.paired > frame and bridge_pairing.paired > previous,
            f"depth image {frame} to complete both pairs",
            lambda: camera.depth_image(stamp + 0.005, millimetres),  # the aligned depth, 5 ms later
        )
        until(lambda: loop._image is not None and loop._image[0].stamp == stamp, "the filter's RGB-D frame")
        header, rgb, depth = loop._image
        assert header.depth is not None and header.depth.intrinsics == COLOUR and np.array_equal(depth, millimetres) and np.array_equal(rgb, pixels)
        payload = relayed.get(TIMEOUT)
        assert payload is not None, "the ingest's sensors/image"
        header, rgb, depth = decode_rgbd(payload)
        assert header.stamp == pytest.approx(stamp) and header.intrinsics == COLOUR and np.array_equal(rgb, pixels)
        assert header.depth is not None and header.depth.intrinsics == COLOUR and header.depth.T_cam_depth is None
        assert depth is not None and depth.dtype == np.uint16 and np.array_equal(depth, millimetres)
        if frame == 0:  # a bad depth image between the two frames: counted by both, the second frame still pairs
            odd = messages.depth_image(stamp + 0.5, millimetres)
            odd.encoding = "8UC1"
            camera.depth.publish(odd)
            until(
                lambda: ingest.bad.counts["ros2_depth_encoding"] == 1 and loop.counters().get("bad_ros2_depth_encoding") == 1,
                "the bad depth image to be counted",
            )
    counters = loop.counters()
    assert counters["images_without_depth"] == 0 and counters["bad_messages"] == 1
    assert ingest.counters()["images_without_depth"] == 0 and ingest.bad.total == 1 and ingest.sent == 2
    ingest.close()
