"""``locnerf eval <experiment>``: the paper's experiments on real data.

Each experiment lives in its own module exposing ``register(subparsers)``; this group only
collects them, so adding an experiment means adding its module to ``EXPERIMENTS``.
"""

from __future__ import annotations

import argparse

from locnerf_cli import eval_place_check, eval_single_image, eval_tracking

EXPERIMENTS = (eval_single_image, eval_tracking, eval_place_check)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf eval``: one sub-subcommand per experiment."""
    experiments = parser.add_subparsers(dest="experiment", required=True)
    for module in EXPERIMENTS:
        module.register(experiments)
