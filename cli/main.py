"""The ``locnerf`` command: one subcommand module per job, each exposing ``register(subparsers)``."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

# Each module registers its subcommand(s) with ``register(subparsers)`` and sets ``func`` on them.
SUBCOMMAND_MODULES = (
    "cli.eval",
    "cli.localize",
    "cli.map",
    "cli.bench",
    "cli.run",
    "cli.up",
    "cli.echo",
    "cli.send",
    "cli.loadtest",
    "cli.certs",
    "cli.fuzz",
)


def build_parser() -> argparse.ArgumentParser:
    """Parser with every subcommand registered."""
    parser = argparse.ArgumentParser(prog="locnerf", description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    args = build_parser().parse_args(argv)
    level = {0: logging.WARNING, 1: logging.INFO}.get(args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as error:
        logging.getLogger("locnerf").error("%s", error)
        return 2


if __name__ == "__main__":
    sys.exit(main())
