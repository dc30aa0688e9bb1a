"""``locnerf demo``: the main job on the embedded default (procedural world, CPU, no network).

Global localization from a lost start in the procedural world: particles in a 2×2×2 m cube with
unknown yaw converge on the camera; prints the errors and writes a PNG of the error curves.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from locnerf.cli.map_source import WORLD, open_map, target_views
from locnerf.config import preset
from locnerf.devices import resolve_device
from locnerf.eval.plots import plot_error_curves
from locnerf.eval.single_image import TrialConfig, run_trials, summarize
from locnerf.filter import Localizer


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="global localization in the procedural world, with a plot")
    parser.add_argument("--trials", type=int, default=5, help="lost starts to recover from")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="folder for the plot")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    world = open_map(WORLD, device)
    generator = torch.Generator().manual_seed(args.seed)
    localizer = Localizer(preset("llff_global"), generator, device=device)
    config = TrialConfig(protocol="global", updates=150, up=world.normalization.up)
    results = run_trials(target_views(world, args.trials, generator), world, localizer, config, total=args.trials)
    for index, result in enumerate(results):
        print(
            f"start {index}: lost by up to 1 m and 180° -> {result.translation_error * 100:.1f} cm, "
            f"{result.rotation_error_deg:.2f}° after {len(result.history_translation)} updates ({result.seconds:.1f} s)"
        )
    plot = plot_error_curves(results, args.out / "global_localization.png", "Global localization in the procedural world")
    print(json.dumps(summarize(results) | {"plot": str(plot)}, indent=2))
    return 0
