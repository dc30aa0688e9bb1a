"""The ``locnerf`` command: one subcommand module per job, each exposing ``add_arguments(parser)``.

The command is the program's entry point, the top layer: it imports the library and the services.
It imports a subcommand's module (and torch, zenoh and the services with it) only when argparse
selects that subcommand, so ``locnerf --help`` lists every subcommand without loading any of them.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from locnerf.errors import LocnerfInputError

logger = logging.getLogger("locnerf")


@dataclass(frozen=True)
class Command:
    """A subcommand: its line in ``locnerf --help`` and the import of its module, whose
    ``add_arguments(parser)`` adds the arguments and sets ``func``."""

    help: str
    load: Callable[[], ModuleType]


COMMANDS: dict[str, Command] = {
    "eval": Command("the paper's experiments (single image, global, tracking)", lambda: importlib.import_module("locnerf_cli.eval")),
    "odometry": Command("RGB-D odometry of a data set's frames as a TUM trajectory", lambda: importlib.import_module("locnerf_cli.odometry")),
    "localize": Command("single-image localization trials (paper protocols)", lambda: importlib.import_module("locnerf_cli.localize")),
    "map": Command("build, evaluate, render and describe map files", lambda: importlib.import_module("locnerf_cli.map")),
    "bench": Command(
        "micro-benchmarks: render (a map), world (the procedural world), filter (hot paths)", lambda: importlib.import_module("locnerf_cli.bench")
    ),
    "run": Command("run one service (ingest, filter, worker, router)", lambda: importlib.import_module("locnerf_cli.run")),
    "up": Command("start ingest, filter and worker(s) locally; Ctrl-C stops them", lambda: importlib.import_module("locnerf_cli.up")),
    "echo": Command("print a topic (pose)", lambda: importlib.import_module("locnerf_cli.echo")),
    "view": Command("watch a running system in rerun (pip install 'locnerf[view]')", lambda: importlib.import_module("locnerf_cli.view")),
    "send": Command("send a command to the filter", lambda: importlib.import_module("locnerf_cli.send")),
    "loadtest": Command(
        "drive the services with a synthetic stream; rates, latency, jitter, losses, CPU", lambda: importlib.import_module("locnerf_cli.loadtest")
    ),
    "bag": Command("ROS 2 bags: info (topics, counts, rates), export (a data set as an MCAP bag)", lambda: importlib.import_module("locnerf_cli.bag")),
    "record": Command("record the filter's ROS 2 outputs and its sensor topics into an MCAP bag", lambda: importlib.import_module("locnerf_cli.record")),
    "certs": Command("a test CA and per-service TLS certificates (CN = role) for Zenoh", lambda: importlib.import_module("locnerf_cli.certs")),
    "fuzz": Command(
        "hostile payloads on every subscribed key of running services; checks counts, memory, pose rate",
        lambda: importlib.import_module("locnerf_cli.fuzz"),
    ),
}


class LazyCommands(argparse._SubParsersAction):
    """Subparsers that list every command at once but fill one in only when argparse selects it."""

    def __init__(self, *args: Any, commands: Mapping[str, Command], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._not_loaded = dict(commands)
        for name, command in commands.items():
            self.add_parser(name, help=command.help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: list[str], option_string: str | None = None) -> None:
        """``values``: the command's name, then its arguments (argparse's remaining arguments)."""
        command = self._not_loaded.pop(values[0], None)
        if command is not None:
            command.load().add_arguments(self._name_parser_map[values[0]])
        super().__call__(parser, namespace, values, option_string)


def build_parser() -> argparse.ArgumentParser:
    """Parser with every subcommand listed (each one's module is imported when it is parsed)."""
    parser = argparse.ArgumentParser(prog="locnerf", description=__doc__.split("\n\n")[0])
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug and the traceback of an input error)")
    parser.add_subparsers(dest="command", required=True, action=LazyCommands, commands=COMMANDS)
    return parser


def ask_torch_for_huge_pages() -> None:
    """Ask PyTorch's CPU allocator for transparent huge pages on large buffers.

    ``THP_MEM_ALLOC_ENABLE`` is read by torch at its first allocation, so it must be set before any
    command imports torch: a map build allocates ~100 MB gradient tensors every step, and faulting
    them in 4 kB pages cost 40-50 ms per step on the 2-core CPU (13 ms with huge pages; docs/MAPS.md).
    Set the variable to 0 to opt out.
    """
    os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code.

    Bad input (a :class:`~locnerf.errors.LocnerfInputError` or a missing file) is reported as one
    line, with its traceback at ``-vv``, and exit code 2; any other exception is a bug and
    propagates with its traceback.
    """
    ask_torch_for_huge_pages()
    args = build_parser().parse_args(argv)
    level = {0: logging.WARNING, 1: logging.INFO}.get(args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (LocnerfInputError, FileNotFoundError) as error:
        logger.error("%s", error, exc_info=args.verbose >= 2)
        return 2


if __name__ == "__main__":
    sys.exit(main())
