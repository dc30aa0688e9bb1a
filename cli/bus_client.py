"""How the client commands (``echo``, ``send``) reach a running system: the bus options they share
and the peer session they open (``locnerf up`` listens on :data:`DEFAULT_ENDPOINT`)."""

from __future__ import annotations

import argparse

from locnerf_services.transport import Bus, TransportConfig, open_bus

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


def open_cli_bus(connect: list[str] | None) -> Bus:
    """A peer session connected to ``connect``, else to the environment's endpoints or the default."""
    config = TransportConfig(connect=(DEFAULT_ENDPOINT,)).with_environment()
    if connect:
        config = config.model_copy(update={"connect": tuple(connect)})
    return open_bus(config)
