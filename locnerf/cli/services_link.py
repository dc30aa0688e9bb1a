"""Where the CLI reaches the service processes and the transport.

The library never imports ``services`` (a layering rule); the CLI is the product's entry point
and the one place that starts them, so it loads them by name at call time. ``import locnerf``
therefore never loads zenoh.
"""

from __future__ import annotations

import argparse
import importlib
from types import ModuleType
from typing import Any

SERVICE_MODULES = {
    "ingest": "services.sensor_ingest.__main__",
    "filter": "services.filter_loop.__main__",
    "worker": "services.nerf_worker.__main__",
    "router": "services.router.__main__",
}


def service_module(name: str) -> ModuleType:
    """The ``__main__`` module of a service (``ingest``, ``filter``, ``worker`` or ``router``)."""
    if name not in SERVICE_MODULES:
        raise ValueError(f"service {name!r}: expected one of {sorted(SERVICE_MODULES)}")
    return importlib.import_module(SERVICE_MODULES[name])


def transport() -> ModuleType:
    """``services.transport``: TransportConfig, open_bus, Inbox."""
    return importlib.import_module("services.transport")


def supervision() -> ModuleType:
    """``services.supervisor``: Supervisor, write_config, free_port."""
    return importlib.import_module("services.supervisor")


def local_hub() -> ModuleType:
    """``services.local_hub``: LocalHub, a listening session and the supervisor of its services."""
    return importlib.import_module("services.local_hub")


def runtime() -> ModuleType:
    """``services.runtime``: load_service_config."""
    return importlib.import_module("services.runtime")


DEFAULT_PORT = 7447
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--robot-id`` and ``--connect`` for the client commands (echo, send)."""
    parser.add_argument("--robot-id", default="robot", help="robot id (keys locnerf/<robot_id>/...)")
    parser.add_argument(
        "--connect",
        action="append",
        help=f"Zenoh endpoint to connect to (repeatable; default: $LOCNERF_ZENOH_CONNECT or {DEFAULT_ENDPOINT}, where `locnerf up` listens)",
    )


def open_cli_bus(connect: list[str] | None) -> Any:
    """A peer session (a ``services.transport.Bus``) connected to ``connect``, else to the
    environment's endpoints or the default."""
    module = transport()
    config = module.TransportConfig(connect=(DEFAULT_ENDPOINT,)).with_environment()
    if connect:
        config = config.model_copy(update={"connect": tuple(connect)})
    return module.open_bus(config)
