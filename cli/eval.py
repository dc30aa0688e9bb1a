"""``locnerf eval <experiment>``: the paper's experiments on real data.

Each experiment lives in its own module exposing ``register(subparsers)``; this group only
collects them, so adding an experiment means adding its module to ``EXPERIMENT_MODULES``.
"""

from __future__ import annotations

import argparse
import importlib

EXPERIMENT_MODULES = (
    "cli.eval_single_image",
    "cli.eval_tracking",
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("eval", help="the paper's experiments (single image, global, tracking)")
    experiments = parser.add_subparsers(dest="experiment", required=True)
    for name in EXPERIMENT_MODULES:
        importlib.import_module(name).register(experiments)
