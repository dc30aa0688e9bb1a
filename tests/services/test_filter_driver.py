"""The filter thread's schedule: odometry is handled and its pose published before any update work."""

from __future__ import annotations

import pytest
import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import SearchRegion
from locnerf.messages import keys
from locnerf.messages.codec import decode, encode, encode_image
from locnerf.messages.schemas import FilterStatus, ImageHeader, Odometry
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.driver import FilterDriver
from locnerf_services.filter_loop.lanes import LaneInbox
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.filter_loop.timings import ThreadTimings
from locnerf_services.transport.memory import MemoryBus

ROBOT = "r"


def test_the_urgent_lane_is_served_first_and_a_full_lane_drops_its_oldest():
    inbox: LaneInbox[str] = LaneInbox(lanes=2, capacity=2)
    for item in ("n1", "n2", "n3"):
        inbox.put(1, item)
    inbox.put(0, "u1")
    assert inbox.dropped == 1 and inbox.waiting(0) == 1 and inbox.waiting(1) == 2
    assert [inbox.get(timeout=0.0) for _ in range(4)] == ["u1", "n2", "n3", None]
    with pytest.raises(IndexError, match="lane 2"):
        inbox.put(2, "x")


def test_timings_summarise_the_odometry_wait_and_each_kind_of_work():
    timings = ThreadTimings(keep=3)
    assert timings.summary().endswith("idle")
    for seconds in (0.001, 0.002, 0.003, 0.004):
        timings.record("odometry", seconds)
    timings.record_wait(0.0005)
    assert len(timings.work["odometry"]) == 3  # the newest kept
    assert "odometry wait 0.50/0.50/0.50" in timings.summary() and "odometry 3.00/" in timings.summary()


def test_queued_odometry_is_published_before_the_update_that_an_image_starts():
    world = ProceduralWorld.default()
    bounds = world.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
    localizer = Localizer(preset("llff").model_copy(update={"particles": 20}), torch.Generator().manual_seed(0), region=region)
    now = [0.0]
    loop = FilterLoop(ROBOT, localizer, world.normalization, region, FilterLoopConfig(), lambda: now[0], world.checksum)
    bus = MemoryBus()
    published: list[str] = []
    bus.subscribe(f"locnerf/{ROBOT}/**", lambda key, _payload: published.append(key.removeprefix(f"locnerf/{ROBOT}/")))
    driver = FilterDriver(loop, bus, clock=lambda: now[0])
    driver.subscribe()
    bus.declare_token(keys.key(ROBOT, keys.WORKER_ALIVE, worker_id="w", device="cpu", map_checksum=world.checksum))
    identity = torch.eye(4, dtype=torch.float64).tolist()
    intrinsics = world.default_intrinsics
    header = ImageHeader(stamp=0.0, encoding="rgb8", width=intrinsics.width, height=intrinsics.height, intrinsics=intrinsics)
    frame = torch.zeros(intrinsics.height, intrinsics.width, 3, dtype=torch.uint8).numpy()
    bus.publish(keys.key(ROBOT, keys.ODOMETRY), encode(Odometry(stamp=0.0, T_odom_body=identity)))
    bus.publish(keys.key(ROBOT, keys.IMAGE), encode_image(header, frame))
    bus.publish(keys.key(ROBOT, keys.ODOMETRY), encode(Odometry(stamp=1 / 15, T_odom_body=identity)))
    mine = len(published)
    for _ in range(4):
        driver.step(timeout=0.0)
    # (the status, due at the first turn, may leave between them: it is no update work)
    outputs = [key.rsplit("/", 1)[0] if key.startswith("update/request") else key for key in published[mine:] if key != "filter/status"]
    assert outputs[:2] == ["filter/pose", "filter/pose"]
    assert "update/request" in outputs[2:]
    assert len(driver.timings.odometry_wait) == 2


def test_the_status_leaves_when_due_while_odometry_keeps_the_thread_busy():
    """Odometry always waiting skips every turn's periodic work; the status still goes out once per period,
    with the images the slot replaced meanwhile (the overload it reports)."""
    world = ProceduralWorld.default()
    bounds = world.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
    localizer = Localizer(preset("llff").model_copy(update={"particles": 20}), torch.Generator().manual_seed(0), region=region)
    now = [0.0]
    loop = FilterLoop(ROBOT, localizer, world.normalization, region, FilterLoopConfig(status_rate=1.0), lambda: now[0], world.checksum)
    bus = MemoryBus()
    statuses: list[FilterStatus] = []
    bus.subscribe(keys.key(ROBOT, keys.STATUS), lambda _key, payload: statuses.append(decode(payload, FilterStatus)))
    driver = FilterDriver(loop, bus, clock=lambda: now[0])
    driver.subscribe()
    identity = torch.eye(4, dtype=torch.float64).tolist()
    intrinsics = world.default_intrinsics
    frame = torch.zeros(intrinsics.height, intrinsics.width, 3, dtype=torch.uint8).numpy()
    for index in range(60):  # 4 s at 15 Hz, two odometry messages queued per turn: one is always waiting
        stamp = index / 15
        header = ImageHeader(stamp=stamp, encoding="rgb8", width=intrinsics.width, height=intrinsics.height, intrinsics=intrinsics)
        bus.publish(keys.key(ROBOT, keys.IMAGE), encode_image(header, frame))
        bus.publish(keys.key(ROBOT, keys.ODOMETRY), encode(Odometry(stamp=stamp, T_odom_body=identity)))
        bus.publish(keys.key(ROBOT, keys.ODOMETRY), encode(Odometry(stamp=stamp + 1 / 30, T_odom_body=identity)))
        now[0] = stamp
        driver.step(timeout=0.0)
    assert len(statuses) == 4  # at 0, 1, 2 and 3 s
    assert statuses[-1].counters["images_replaced"] > 0
