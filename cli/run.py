"""``locnerf run ingest|filter|worker|router [--config FILE]``: one service process in the foreground."""

from __future__ import annotations

import argparse
from types import ModuleType

import locnerf_services.filter_loop.__main__ as filter_process
import locnerf_services.nerf_worker.__main__ as worker_process
import locnerf_services.router.__main__ as router_process
import locnerf_services.sensor_ingest.__main__ as ingest_process

# Each service's ``__main__`` module: its ``add_arguments(parser)`` and ``run(args)``, with the help line.
SERVICES: dict[str, tuple[ModuleType, str]] = {
    "ingest": (ingest_process, "publish a sensor stream (procedural world along a trajectory)"),
    "filter": (filter_process, "the particle filter: predicts on odometry, merges worker updates, publishes the pose"),
    "worker": (worker_process, "a NeRF worker: renders particles for update requests"),
    "router": (router_process, "a Zenoh router from a zenohd JSON5 file (where zenohd is not installed)"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf run``: one sub-subcommand per service, with that service's options."""
    services = parser.add_subparsers(dest="service", required=True)
    for name, (module, help_line) in SERVICES.items():
        service_parser = services.add_parser(name, help=help_line)
        module.add_arguments(service_parser)
        service_parser.set_defaults(func=module.run)
