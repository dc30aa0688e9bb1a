"""``python -m services.filter_loop``: the filter process (one thread owns the filter state)."""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from pathlib import Path

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.config import PRESETS, load_config, preset
from locnerf.devices import resolve_device
from locnerf.errors import ConfigError
from locnerf.field.map_info import metric_frame_problem
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig, SearchRegion
from locnerf.maps.keyframes import recovery_keyframes
from locnerf.maps.source import map_identity, open_map
from locnerf_services.filter_loop.driver import FilterDriver
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.runtime import limit_torch_threads, load_service_config, prefer_latency_over_throughput, service_main, stop_on_signals
from locnerf_services.transport import Bus, TransportConfig, open_bus

logger = logging.getLogger(__name__)


class FilterProcessConfig(BaseModel):
    """A filter-loop process."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    robot_id: str = Field("robot", description="Robot whose keys the filter uses.")
    map: str = Field("world", description="Map whose frame, scale and bounds the filter uses: 'world' or a map file.")
    device: str = Field("auto", description="auto, cpu, cuda or cuda:N, for the particles.")
    localizer: str = Field("llff", description="Localizer preset name (llff, llff_global, jackal) or a localizer TOML file.")
    seed: int = Field(0, description="Seed of every random draw of the filter.")
    loop: FilterLoopConfig = Field(default_factory=FilterLoopConfig, description="Timing and fault handling.")
    torch_threads: int = Field(1, ge=1, description="Intra-op threads of torch in this process (1 suits several services per machine).")
    transport: TransportConfig = Field(default_factory=TransportConfig, description="Zenoh session settings.")
    ros2: Ros2Config = Field(default_factory=Ros2Config, description="ROS 2 over rmw_zenoh: topics in and out (docs/ROS2.md).")


def localizer_config(spec: str) -> LocalizerConfig:
    """A preset name or the path of a localizer TOML file."""
    return preset(spec) if spec in PRESETS else load_config(spec)


def build_loop(config: FilterProcessConfig) -> FilterLoop:
    """The filter loop for ``config`` (loads the map for its frame and bounds)."""
    device = resolve_device(config.device)
    radiance_map = open_map(config.map, device)
    problem = metric_frame_problem(getattr(radiance_map, "metadata", {}))
    if problem is not None:
        raise ConfigError(f"map {config.map}: {problem}")
    normalization = radiance_map.normalization
    bounds = radiance_map.camera_bounds()
    region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()), up=normalization.up)
    generator = torch.Generator().manual_seed(config.seed)
    localizer_settings = localizer_config(config.localizer)
    keyframes = recovery_keyframes(localizer_settings, radiance_map, radiance_map.default_intrinsics, config.seed)
    localizer = Localizer(localizer_settings, generator, device=device, region=region, keyframes=keyframes)
    return FilterLoop(config.robot_id, localizer, normalization, region, config.loop, time.monotonic, map_identity(radiance_map))


def serve(loop: FilterLoop, bus: Bus, stop: threading.Event, ros2: Ros2Config | None = None) -> None:
    """Run the loop until ``stop``: callbacks only enqueue, this thread does all the work, odometry
    first (:mod:`services.filter_loop.driver`); with ``ros2`` enabled it also speaks ROS 2."""
    bridge = None
    if ros2 is not None and ros2.enabled:
        from locnerf_services.ros2.filter_bridge import FilterRos2Bridge

        bridge = FilterRos2Bridge(loop, bus, ros2)
        logger.info("ROS 2 node %s in domain %d (session %s)", ros2.node_name, ros2.domain_id, bus.session_id)
    driver = FilterDriver(loop, bus, ros2=bridge)
    handles = driver.subscribe()
    logger.info("filter loop serving robot %s", loop.robot_id)
    try:
        while not stop.is_set():
            driver.step(timeout=0.01)
    finally:
        for handle in handles:
            handle.close()
        loop.close()
        logger.info("%s", driver.timings.summary())
        logger.info("counters at exit: %s", loop.counters())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Command-line options of the filter."""
    parser.add_argument("--config", type=Path, help="TOML file with FilterProcessConfig fields")
    parser.add_argument("--robot-id", dest="robot_id", help="robot id (overrides the file)")
    parser.add_argument("--map", help="'world' or a map file (overrides the file)")
    parser.add_argument("--device", help="auto, cpu, cuda or cuda:N (overrides the file)")
    parser.add_argument("--localizer", help="preset name or localizer TOML file (overrides the file)")
    parser.add_argument("--seed", type=int, help="seed (overrides the file)")


def run(args: argparse.Namespace) -> int:
    """Build the filter, open the bus and serve until SIGINT/SIGTERM."""
    overrides = {k: getattr(args, k) for k in ("robot_id", "map", "device", "localizer", "seed")}
    config = load_service_config(FilterProcessConfig, args.config, overrides)
    limit_torch_threads(config.torch_threads)
    prefer_latency_over_throughput()
    loop = build_loop(config)
    stop = stop_on_signals()
    bus = open_bus(config.transport.with_environment())
    try:
        serve(loop, bus, stop, config.ros2)
    finally:
        bus.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return service_main("python -m services.filter_loop", __doc__, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
