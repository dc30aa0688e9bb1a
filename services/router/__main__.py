"""``python -m services.router``: a Zenoh router from a zenohd JSON5 file, where zenohd is not installed."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from locnerf.errors import LocnerfInputError
from locnerf_services.runtime import service_main, stop_on_signals
from locnerf_services.transport.router import Router, router_config

logger = logging.getLogger(__name__)


def parse_override(text: str) -> tuple[str, str]:
    """``KEY:VALUE`` (zenohd's ``--cfg``): a config path and a JSON5 value.

    Raises:
        LocnerfInputError: no ``:`` separating a key from a value.
    """
    key, separator, value = text.partition(":")
    if not separator or not key or not value:
        raise LocnerfInputError(f"--cfg {text!r}: expected KEY:VALUE, e.g. 'listen/endpoints:[\"tls/127.0.0.1:7447\"]'")
    return key, value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Command-line options of the router."""
    parser.add_argument("--config", type=Path, default=Path("deploy/zenoh/router.json5"), help="zenohd JSON5 file (default deploy/zenoh/router.json5)")
    parser.add_argument(
        "--cfg", action="append", default=[], help="KEY:VALUE override as for zenohd, e.g. 'listen/endpoints:[\"tcp/127.0.0.1:7447\"]' (repeatable)"
    )


def run(args: argparse.Namespace) -> int:
    """Open the router and hold it until SIGINT/SIGTERM."""
    conf = router_config(args.config, [parse_override(text) for text in args.cfg])
    stop = stop_on_signals()
    router = Router(conf)
    logger.info("router %s up (%s)", router.zid, args.config)
    try:
        stop.wait()
    finally:
        router.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return service_main("python -m services.router", __doc__, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
