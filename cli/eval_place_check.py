"""``locnerf eval place-check``: does the keyframe index place a sequence's images at their own pose, and not at far ones?

The evidence for a configuration's ``recovery.place_check_*`` on a map (:mod:`locnerf.eval.place_check`): run it on
the robot's own recorded sequence before turning the check on.
"""

from __future__ import annotations

import argparse
import json

import torch

from locnerf.config import load_config
from locnerf.errors import LocnerfInputError
from locnerf.eval.place_check import place_check_report, place_images
from locnerf.maps.keyframes import recovery_keyframes
from locnerf.maps.source import WORLD, open_map
from locnerf.sim.scenario import ScenarioConfig, build_scenario
from locnerf_cli.eval_tracking import camera_path
from locnerf_cli.flags import add_poses_argument


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("place-check", help="how well the keyframe index tells a sequence's places apart (recovery.place_check_*)")
    parser.add_argument("--map", required=True, help="map file")
    parser.add_argument("--sequence", required=True, help="data-set folder (NeRF-synthetic, 7-Scenes, ...) whose images are placed")
    parser.add_argument("--split", default="test", help="which split of the sequence folder")
    parser.add_argument("--frame-rate", type=float, default=None, help="replay at the capture's rate, frames per second (7-Scenes: 30), instead of --speed")
    parser.add_argument("--speed", type=float, default=0.66, help="nominal camera speed, data-set units per second")
    parser.add_argument("--downscale", type=int, default=None, help="image size divisor (default: the data set's)")
    parser.add_argument("--image-rate", type=float, default=5.0, help="images per second along the sequence")
    parser.add_argument("--config", required=True, help="TOML localizer configuration: its keyframe index (lattice, reference views) and place check")
    parser.add_argument("--views", type=int, default=None, help="best views per image (default: the configuration's recovery.place_check_views)")
    parser.add_argument("--position", type=float, default=None, help="reach of the check, map units (default: recovery.place_check_position)")
    parser.add_argument("--rotation", type=float, default=None, help="reach of the check, degrees (default: recovery.place_check_rotation_deg)")
    parser.add_argument(
        "--away", type=float, nargs=2, metavar=("UNITS", "DEGREES"), default=(0.9, 20.0), help="pairs of images at least this far apart (a kidnapping's jump)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the index's reference views (as eval tracking's --seed)")
    parser.add_argument("--json", action="store_true", help="one line of JSON")
    add_poses_argument(parser)
    parser.set_defaults(func=run, odom_rate=15.0, background="white", passes=1)


def run(args: argparse.Namespace) -> int:
    if args.sequence == WORLD:
        raise LocnerfInputError("--sequence world: expected a data-set folder (the procedural world has no fixed sequence of images)")
    config = load_config(args.config)
    if not config.uses_keyframes():
        raise LocnerfInputError(f"--config {args.config}: its recovery and start draw around no keyframes, so there is no index to check")
    recovery = config.recovery
    views = args.views if args.views is not None else recovery.place_check_views
    if views < 1:
        raise LocnerfInputError(f"--views {views} (recovery.place_check_views of {args.config}): expected at least one view per image")
    position = args.position if args.position is not None else recovery.place_check_position
    rotation = args.rotation if args.rotation is not None else recovery.place_check_rotation_deg
    radiance_map = open_map(args.map, torch.device("cpu"))
    path = camera_path(args, radiance_map)
    scenario = build_scenario(path, ScenarioConfig(image_rate=args.image_rate, seed=args.seed), radiance_map.normalization)
    index = recovery_keyframes(config, radiance_map, path.intrinsics, args.seed + 2)
    generator = torch.Generator().manual_seed(args.seed + 1)
    ticks = scenario.image_ticks
    images = [scenario.image(tick, generator) for tick in ticks]
    placed = place_images(index, images, scenario.stamps[ticks], scenario.truth[ticks], views)
    report = {"views": views, "position": position, "rotation_deg": rotation, "away": list(args.away), "keyframes": len(index)}
    report |= place_check_report(placed, position, rotation, *args.away)
    print(json.dumps(report) if args.json else json.dumps(report, indent=2))
    return 0
