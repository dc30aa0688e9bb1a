"""``locnerf record BAG``: record what the filter publishes on ROS 2 (``amcl_pose``, ``particle_cloud``,
``/tf``) with the sensor topics it reads into an MCAP rosbag2 (``ros2 bag``, Foxglove, evo open it).

The filter must speak ROS 2 (``[ros2] enabled = true``, docs/ROS2.md); the topics, domain and
namespace are those of its ``[ros2]`` table (``--config``, a filter configuration or a file of
``Ros2Config`` fields). Ctrl-C (or ``--duration``) stops and closes the bag.
"""

from __future__ import annotations

import argparse
import logging
import time
import tomllib
from pathlib import Path

from pydantic import ValidationError

from locnerf.bags.writer import BagWriter
from locnerf.errors import ConfigError, LocnerfInputError
from locnerf.ros2.types import typestore
from locnerf_cli.bus_client import open_cli_bus
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.recorder import Ros2Recorder, default_topics
from locnerf_services.runtime import stop_on_signals

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="the bag folder to create (must not exist)")
    parser.add_argument(
        "--config", type=Path, default=None, help="filter configuration with a [ros2] table, or a file of its fields (default: nav2_amcl's names)"
    )
    parser.add_argument("--no-inputs", action="store_true", help="only the filter's outputs, not its sensor topics")
    parser.add_argument(
        "--topic", action="append", default=[], metavar="NAME=TYPE", help="another topic, e.g. /ground_truth=geometry_msgs/msg/PoseStamped (repeatable)"
    )
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: at Ctrl-C)")
    parser.add_argument("--connect", action="append", help="Zenoh endpoint (repeatable; default: $LOCNERF_ZENOH_CONNECT or tcp/127.0.0.1:7447)")
    parser.set_defaults(func=run)


def ros2_config(path: Path | None) -> Ros2Config:
    """The ``[ros2]`` table of ``path`` (or its top level); defaults without a file.

    Raises:
        ConfigError: not TOML, or invalid fields (naming the file).
    """
    if path is None:
        return Ros2Config()
    try:
        data = tomllib.loads(path.read_text())
        return Ros2Config.model_validate(data.get("ros2", data))
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML ({error})") from None
    except ValidationError as error:
        raise ConfigError(f"{path}: invalid [ros2] settings (Ros2Config):\n{error}") from None


def extra_topics(values: list[str]) -> list[tuple[str, str]]:
    """``NAME=TYPE`` flags -> (name, type), the type known to the type store.

    Raises:
        LocnerfInputError: a flag without ``=`` or a type the type store does not hold.
    """
    topics = []
    for value in values:
        name, separator, ros_type = value.partition("=")
        if not separator or not name or ros_type not in typestore().fielddefs:
            raise LocnerfInputError(f"--topic {value!r}: expected NAME=TYPE with a ROS 2 message type such as geometry_msgs/msg/PoseStamped")
        topics.append((name, ros_type))
    return topics


def run(args: argparse.Namespace) -> int:
    config = ros2_config(args.config)
    topics = default_topics(config, inputs=not args.no_inputs) + extra_topics(args.topic)
    stop = stop_on_signals()
    deadline = time.monotonic() + args.duration if args.duration > 0 else float("inf")
    bus = open_cli_bus(args.connect)
    try:
        with BagWriter(args.bag) as bag:
            recorder = Ros2Recorder(bus, bag, topics, config.domain_id, config.namespace)
            logger.info("recording %s into %s", ", ".join(name for name, _ in topics), args.bag)
            try:
                while not stop.is_set() and time.monotonic() < deadline:
                    recorder.step(0.1)
                recorder.step(0.0)
            finally:
                recorder.close()
    finally:
        bus.close()
    return 0
