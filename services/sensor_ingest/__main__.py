"""``python -m services.sensor_ingest``: publish a sensor stream (procedural world or a replay) on the bus."""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.colour_camera import colour_camera_matrix, with_colour_camera
from locnerf.data.detect import read_dataset
from locnerf.data.euroc import read_euroc
from locnerf.errors import ConfigError
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus
from locnerf.sim.events import OdometryEvent, RgbdFrameEvent, SensorEvent
from locnerf.sim.world import ProceduralWorld
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.runtime import (
    BadMessages,
    StatusPublisher,
    default_instance_id,
    limit_torch_threads,
    load_service_config,
    prefer_latency_over_throughput,
    service_main,
    stop_on_signals,
)
from locnerf_services.sensor_ingest.camera_source import CameraSourceConfig, camera_events
from locnerf_services.sensor_ingest.euroc_source import EurocSourceConfig, euroc_events
from locnerf_services.sensor_ingest.odometry_stage import OdometryStage, OnlineOdometryConfig
from locnerf_services.sensor_ingest.prefetch import PrefetchedEvents
from locnerf_services.sensor_ingest.replay_source import ReplaySourceConfig, replay_events
from locnerf_services.sensor_ingest.ros2_source import Ros2Ingest
from locnerf_services.sensor_ingest.rosbag_source import RosbagSourceConfig, rosbag_events
from locnerf_services.sensor_ingest.scenario_source import ScenarioSourceConfig, scenario_events
from locnerf_services.sensor_ingest.service import Pacer, ProgressLog, event_message
from locnerf_services.sensor_ingest.world_source import WorldSourceConfig, world_events
from locnerf_services.transport import Bus, Inbox, TransportConfig, open_bus

logger = logging.getLogger(__name__)


class IngestConfig(BaseModel):
    """A sensor-ingest process."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    robot_id: str = Field("robot", description="Robot whose sensor keys are published.")
    ingest_id: str = Field("", description="Name of this ingest in its status key (empty: <hostname>-<pid>).")
    source: Literal["world", "replay", "scenario", "euroc", "camera", "ros2", "rosbag"] = Field(
        "world",
        description="Stream source: the procedural world along a trajectory, the replay of a posed image sequence, "
        "the offline tracking experiment's scenario (its path, images, kidnapping and seeds, as `locnerf eval tracking`), "
        "a EuRoC MAV folder (its stamps kept, odometry synthesised from its ground truth), "
        "a live camera / video file (images only; odometry comes from the robot on sensors/odom), "
        "a ROS 2 robot's odometry and camera topics over rmw_zenoh (docs/ROS2.md), "
        "or a ROS 2 bag's odometry, camera and ground-truth topics at their stamps (docs/BAGS.md).",
    )
    world: WorldSourceConfig = Field(default_factory=WorldSourceConfig, description="Rates, duration and noise of the world stream.")
    replay: ReplaySourceConfig = Field(default_factory=ReplaySourceConfig, description="Sequence, rates and noise of the replay.")
    scenario: ScenarioSourceConfig = Field(
        default_factory=ScenarioSourceConfig, description="Path, rates, odometry errors and kidnapping of the tracking scenario."
    )
    euroc: EurocSourceConfig = Field(default_factory=EurocSourceConfig, description="EuRoC folder, camera, rates and noise.")
    camera: CameraSourceConfig = Field(default_factory=CameraSourceConfig, description="Capture device or video file and its calibration.")
    rosbag: RosbagSourceConfig = Field(default_factory=RosbagSourceConfig, description="With source = 'rosbag': the bag and its topic names.")
    ros2: Ros2Config = Field(
        default_factory=Ros2Config, description="With source = 'ros2': domain, namespace, sensor topics and frames (enabled and the output fields are unused)."
    )
    odometry: OnlineOdometryConfig = Field(
        default_factory=OnlineOdometryConfig,
        description="Online RGB-D odometry of a source that gives RGB-D frames instead of odometry (the scenario with odometry.source = 'rgbd').",
    )
    speed: float = Field(1.0, ge=0, description="Sensor seconds per wall second (0: as fast as possible).")
    seed: int = Field(0, description="Seed of the noise draws.")
    wait_for_workers: int = Field(0, ge=0, description="Before streaming, wait until the filter reports this many live workers (0: start at once).")
    wait_timeout: float = Field(120.0, gt=0, description="Longest wait for the filter and workers, seconds.")
    prefetch_events: int = Field(32, ge=0, description="Events produced ahead of their release by a background thread (0: produced inline, between releases).")
    prefetch_nice: int = Field(
        10, ge=0, le=19, description="Niceness added to the producing thread: frame rendering yields the CPU to the release of odometry."
    )
    prefill: bool = Field(
        False,
        description="Before the first release, wait until prefetch_events events are produced (or the source ended): "
        "a load test renders its whole stream before the clock starts, so the machine it measures does only the services' work.",
    )
    torch_threads: int = Field(1, ge=1, description="Intra-op threads of torch in this process (1 suits several services per machine).")
    progress_interval: float = Field(30.0, ge=0, description="Wall seconds between log lines of streaming progress (events, frames, rates; 0: none).")
    transport: TransportConfig = Field(default_factory=TransportConfig, description="Zenoh session settings.")


def wait_for_workers(bus: Bus, robot_id: str, count: int, timeout: float, stop: threading.Event, status: StatusPublisher) -> bool:
    """Block until a FilterStatus lists at least ``count`` workers; False on timeout or stop.

    Bad status messages are counted by kind in ``status.bad`` (published by ``status``) and dropped."""
    inbox: Inbox[bytes] = Inbox(capacity=64)
    subscription = bus.subscribe(keys.key(robot_id, keys.STATUS), lambda _k, payload: inbox.put(payload))
    deadline = time.monotonic() + timeout
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            status.publish_if_due({"events_sent": 0, "inbox_dropped": inbox.dropped})
            payload = inbox.get(timeout=0.2)
            if payload is None:
                continue
            try:
                if len(decode(payload, FilterStatus).workers) >= count:
                    return True
            except DecodeError as error:
                status.bad.record(error.kind, error.reason)
        return False
    finally:
        subscription.close()


def sensor_events(config: IngestConfig, bad: BadMessages | None = None) -> Iterator[SensorEvent]:
    """The configured source's event stream; a bag's bad messages are counted in ``bad`` (None: a new one).

    Raises:
        ConfigError: a replay or EuRoC source without a path, a camera without intrinsics or that cannot be opened.
    """
    if config.source == "ros2":
        raise ValueError("source = 'ros2' has no event stream: it relays the ROS 2 topics as they arrive (relay_ros2)")
    if config.source == "world":
        return world_events(ProceduralWorld.default(), config.world, config.seed)
    if config.source == "camera":
        return camera_events(config.camera)
    if config.source == "scenario":
        return scenario_events(config.scenario, config.seed, online_rgbd=True)
    if config.source == "rosbag":
        return rosbag_events(config.rosbag, (bad or BadMessages("sensor_ingest")).record)
    generator = torch.Generator().manual_seed(config.seed)
    if config.source == "euroc":
        if not config.euroc.path:
            raise ConfigError("source = 'euroc' needs euroc.path: the folder holding mav0/")
        sequence = read_euroc(config.euroc.path, config.euroc.camera, config.euroc.groundtruth or None)
        return euroc_events(sequence, config.euroc, generator)
    if not config.replay.path:
        raise ConfigError("source = 'replay' needs replay.path: the data-set folder to replay")
    replay = config.replay
    T_depth_colour = None if replay.T_depth_colour is None else colour_camera_matrix(replay.T_depth_colour)
    sequence = read_dataset(
        replay.path,
        split=replay.split,
        downscale=replay.downscale,
        skip_missing=replay.skip_missing,
        poses=replay.poses,
        T_depth_colour=T_depth_colour if replay.poses == "sfm" else None,
    )
    if T_depth_colour is not None and sequence.T_cam_depth is None:
        sequence = with_colour_camera(sequence, T_depth_colour)
    return replay_events(sequence, config.replay, generator)


def relay_ros2(bus: Bus, config: IngestConfig, stop: threading.Event, status: StatusPublisher) -> dict[str, int]:
    """Republish the ROS 2 sensor topics until ``stop`` (with ``odometry.ros2_frames``, odometry computed
    from the RGB-D frames); returns the counters (messages sent, ...) that ``status`` reports.

    Raises:
        ConfigError: ``odometry.ros2_frames`` without ``ros2.depth_topic`` or with a robot odometry topic.
    """
    online = config.odometry.ros2_frames
    if online and (not config.ros2.depth_topic or config.ros2.odometry_topic):
        raise ConfigError(
            f"odometry.ros2_frames with ros2.depth_topic {config.ros2.depth_topic!r} and ros2.odometry_topic {config.ros2.odometry_topic!r}: "
            "expected a depth topic and odometry_topic = '' (the odometry is computed from the colour and depth frames)"
        )
    with contextlib.ExitStack() as stack:
        stage = stack.enter_context(OdometryStage(config.odometry, lambda event: bus.publish(*event_message(config.robot_id, event)))) if online else None
        ingest = Ros2Ingest(bus, config.robot_id, config.ros2, status.bad, odometry=stage)
        stack.callback(ingest.close)
        logger.info(
            "ros2 ingest: node %s_ingest in domain %d%s", config.ros2.node_name, config.ros2.domain_id, ", odometry from RGB-D frames" if online else ""
        )
        while not stop.is_set():
            ingest.step(timeout=0.05)
            status.publish_if_due(ingest.counters())
    return ingest.counters(timings=True)


def stream(bus: Bus, config: IngestConfig, stop: threading.Event, status: StatusPublisher) -> dict[str, int]:
    """Publish the configured stream, RGB-D frames turned into odometry online (:class:`OdometryStage`);
    returns the counters (events sent, the online odometry's) that ``status`` reports every second."""
    events: Iterable[SensorEvent] = sensor_events(config, status.bad)
    sent = 0
    progress = ProgressLog(config.progress_interval)
    stage: OdometryStage | None = None

    def publish_odometry(event: OdometryEvent) -> None:
        bus.publish(*event_message(config.robot_id, event))

    def counters(final: bool = False) -> dict[str, int]:
        return {"events_sent": sent} | ({} if stage is None else stage.counters(timings=final))

    with contextlib.ExitStack() as stack:
        if config.prefetch_events:
            prefetched = stack.enter_context(PrefetchedEvents(events, config.prefetch_events, config.prefetch_nice))
            if config.prefill:
                logger.info("producing up to %d events before the first release", config.prefetch_events)
                while not prefetched.wait_until_filled(0.2):
                    if stop.is_set():
                        return counters()
            events = prefetched
        for event in Pacer(config.speed).paced(events, stop.is_set):
            if isinstance(event, RgbdFrameEvent):
                if stage is None:
                    stage = stack.enter_context(OdometryStage(config.odometry, publish_odometry))
                stage.submit(event)
            else:
                bus.publish(*event_message(config.robot_id, event))
                sent += 1
            status.publish_if_due(counters())
            progress.sent(event)
    return counters(final=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Command-line options of the ingest."""
    parser.add_argument("--config", type=Path, help="TOML file with IngestConfig fields")
    parser.add_argument("--robot-id", dest="robot_id", help="robot id (overrides the file)")
    parser.add_argument("--speed", type=float, help="sensor seconds per wall second, 0 = as fast as possible (overrides the file)")
    parser.add_argument("--seed", type=int, help="seed of the noise (overrides the file)")
    parser.add_argument("--duration", type=float, help="seconds of sensor time to stream (overrides world.duration)")
    parser.add_argument("--wait-for-workers", dest="wait_for_workers", type=int, help="wait for this many live workers first")


def run(args: argparse.Namespace) -> int:
    """Stream until the source ends or SIGINT/SIGTERM."""
    overrides = {k: getattr(args, k) for k in ("robot_id", "speed", "seed", "wait_for_workers")}
    config = load_service_config(IngestConfig, args.config, overrides)
    if args.duration is not None:
        config = IngestConfig.model_validate(config.model_dump() | {"world": config.world.model_dump() | {"duration": args.duration}})
    limit_torch_threads(config.torch_threads)
    prefer_latency_over_throughput()
    stop = stop_on_signals()
    bus = open_bus(config.transport.with_environment())
    ingest_id = config.ingest_id or default_instance_id()
    status = StatusPublisher(
        bus.publish, keys.key(config.robot_id, keys.INGEST_STATUS, ingest_id=ingest_id), "sensor_ingest", ingest_id, BadMessages("sensor_ingest")
    )
    try:
        if config.wait_for_workers and not wait_for_workers(bus, config.robot_id, config.wait_for_workers, config.wait_timeout, stop, status):
            if stop.is_set():
                return 0
            logger.error("no filter with %d live worker(s) within %.0f s: not streaming", config.wait_for_workers, config.wait_timeout)
            return 1
        counters = relay_ros2(bus, config, stop, status) if config.source == "ros2" else stream(bus, config, stop, status)
        status.publish_if_due(counters, force=True)
        logger.info("ingest: %d events sent; counters %s", counters["events_sent"], counters)
    finally:
        bus.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return service_main("python -m services.sensor_ingest", __doc__, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
