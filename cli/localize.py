"""``locnerf localize``: single-image localization trials on a map, printed as JSON or a table."""

from __future__ import annotations

import argparse
import json
import logging

import torch

from locnerf.config import load_config, preset
from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.eval.single_image import TrialConfig, run_trials, summarize
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig
from locnerf.maps.source import open_map, target_views
from locnerf_cli.flags import from_flags

logger = logging.getLogger(__name__)

DEFAULT_PRESET = {"inerf": "llff", "global": "llff_global"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf localize``."""
    parser.add_argument("--map", default="world", help="'world' (the procedural world) or a map file")
    parser.add_argument("--protocol", choices=("inerf", "global"), default="inerf", help="initial distribution")
    parser.add_argument("--trials", type=int, default=20, help="number of trials")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    parser.add_argument("--updates", type=int, default=None, help="update steps per trial (protocol default if unset)")
    parser.add_argument("--preset", default=None, help="filter preset (llff for inerf, llff_global for global if unset)")
    parser.add_argument("--config", default=None, help="TOML localizer configuration (overrides --preset)")
    parser.add_argument("--particles", type=int, default=None, help="override the preset's particle count")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(func=run)


DEFAULT_UPDATES = {"inerf": 100, "global": 150}


def run(args: argparse.Namespace) -> int:
    if args.trials < 1:
        raise LocnerfInputError(f"--trials {args.trials}: expected at least 1")
    device = resolve_device(args.device)
    radiance_map = open_map(args.map, device)
    config = load_config(args.config) if args.config else preset(args.preset or DEFAULT_PRESET[args.protocol])
    if args.particles is not None:
        config = from_flags(LocalizerConfig, config.model_dump() | {"particles": args.particles})
    trial_config = TrialConfig(
        protocol=args.protocol,
        updates=args.updates or DEFAULT_UPDATES[args.protocol],
        up=radiance_map.normalization.up,
    )
    generator = torch.Generator().manual_seed(args.seed)
    localizer = Localizer(config, generator, device=device)
    views = target_views(radiance_map, args.trials, generator)
    results = run_trials(views, radiance_map, localizer, trial_config, show_progress=not args.json, total=args.trials)
    summary = summarize(results) | {
        "map": args.map,
        "protocol": args.protocol,
        "seed": args.seed,
        "particles": config.particles,
        "updates": trial_config.updates,
        "device": str(device),
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key:>28}: {value}")
    return 0
