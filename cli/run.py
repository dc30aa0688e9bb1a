"""``locnerf run ingest|filter|worker|router [--config FILE]``: one service process in the foreground."""

from __future__ import annotations

import argparse

from cli.services_link import SERVICE_MODULES, service_module

_HELP = {
    "ingest": "publish a sensor stream (procedural world along a trajectory)",
    "filter": "the particle filter: predicts on odometry, merges worker updates, publishes the pose",
    "worker": "a NeRF worker: renders particles for update requests",
    "router": "a Zenoh router from a zenohd JSON5 file (where zenohd is not installed)",
}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("run", help="run one service (ingest, filter, worker, router)")
    services = parser.add_subparsers(dest="service", required=True)
    for name in SERVICE_MODULES:
        module = service_module(name)
        service_parser = services.add_parser(name, help=_HELP[name])
        module.add_arguments(service_parser)
        service_parser.set_defaults(func=module.run)
