"""``locnerf eval tracking``: follow a camera path with odometry and images, report the error over time."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

from locnerf.bags.reader import bag_extent, is_bag
from locnerf.bags.scenario import bag_scenario
from locnerf.config import load_config, preset
from locnerf.data.colour_camera import check_map_poses, map_colour_camera
from locnerf.data.map_lens import map_lens
from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.eval.tracking import (
    BACK_ON_TRACK,
    ConvergenceConfig,
    StartConfig,
    convergence_stamps,
    error_series,
    run_tracking,
    search_region,
    summarize_tracking,
)
from locnerf.eval.tracking_plots import plot_tracking_errors
from locnerf.field.protocol import RadianceMap
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig
from locnerf.maps.keyframes import recovery_keyframes
from locnerf.maps.source import WORLD, open_map
from locnerf.odometry.sequence import RGBD, SYNTHETIC
from locnerf.sim.kidnap import KidnapJump, kidnap_shift_for_jump
from locnerf.sim.paths import CameraPath, WorldPath, read_sequence_path
from locnerf.sim.scenario import ScenarioConfig, build_scenario, check_timeline
from locnerf.sim.sensors import CameraConfig, VioConfig
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld
from locnerf_cli import eval_tracking_odometry
from locnerf_cli.eval_tracking_live import run_live
from locnerf_cli.flags import NO_DEPTH_HELP, add_poses_argument, from_flags, without_depth
from locnerf_cli.tracking_flags import add_odometry_arguments


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("tracking", help="tracking along a path with odometry, optional kidnapping (paper Fig. 5)")
    parser.add_argument("--map", required=True, help="map file, or 'world' for the procedural world")
    parser.add_argument(
        "--sequence",
        required=True,
        help="'world' (figure-eight in the procedural world), a data-set folder (NeRF-synthetic, 7-Scenes, ...) or a ROS 2 bag "
        "(its odometry, images and ground truth, docs/BAGS.md; the odometry and image flags do not apply)",
    )
    parser.add_argument("--split", default="test", help="sequence folder: which split to replay (transforms_<split>.json, 7-Scenes TestSplit.txt, ...)")
    parser.add_argument("--background", default="white", help="NeRF-synthetic sequence: colour the RGBA frames are composited on (white, black)")
    parser.add_argument(
        "--downscale", type=int, default=None, help="sequence folder: image size divisor (default: the data set's, 1 for NeRF-synthetic, 4 for 7-Scenes)"
    )
    parser.add_argument("--speed", type=float, default=0.66, help="sequence folder: nominal camera speed, data-set units per second")
    parser.add_argument(
        "--frame-rate",
        type=float,
        default=None,
        help="sequence folder: replay a recorded video at its capture rate, frames per second (7-Scenes: 30), instead of --speed;"
        " a whole multiple of --odom-rate",
    )
    parser.add_argument("--duration", type=float, default=None, help="length of the run, seconds (default: one loop)")
    add_odometry_arguments(parser)
    eval_tracking_odometry.add_arguments(parser)
    parser.add_argument("--image-rate", type=float, default=None, help="images per second (default: 3 offline, 5 with --live)")
    parser.add_argument(
        "--updates-per-image",
        type=int,
        default=1,
        help="updates on each image (noise-only prediction between them; --live: repeats while no newer image has come, each after the last merged)",
    )
    parser.add_argument("--init", choices=("global", "gaussian"), default="global", help="start: the paper's global cube, or a Gaussian around the truth")
    parser.add_argument("--kidnap-at", type=float, default=None, help="seconds: the camera jumps half a loop ahead, unseen by the odometry")
    parser.add_argument(
        "--kidnap-jump",
        type=float,
        nargs=2,
        metavar=("METRES", "DEGREES"),
        default=None,
        help="with --kidnap-at: jump to the pose of the path at least this far and this much turned, nearest to both (locnerf.sim.kidnap)"
        " instead of half a loop ahead",
    )
    parser.add_argument("--no-recovery", action="store_true", help="turn kidnapping recovery off in the chosen configuration")
    parser.add_argument("--no-depth", action="store_true", help=NO_DEPTH_HELP)
    parser.add_argument("--converged-translation", type=float, default=0.05, help="convergence: translation error threshold, map units")
    parser.add_argument("--converged-rotation", type=float, default=5.0, help="convergence: rotation error threshold, degrees")
    parser.add_argument("--converged-hold", type=float, default=2.0, help="convergence: seconds both errors must stay under the thresholds")
    parser.add_argument(
        "--back-on-track",
        type=float,
        nargs=3,
        metavar=("UNITS", "DEGREES", "SECONDS"),
        default=None,
        help="after a kidnapping: back when both errors stay under these thresholds this long (back_on_track_s; default 0.03 map units, 1 deg, 1 s); "
        "the tracked filter's own wait for such a hold: start.back_on_track_while_tracking",
    )
    parser.add_argument("--preset", default="tracking", help="filter preset (tracking, llff, llff_global, jackal)")
    parser.add_argument("--config", default=None, help="TOML localizer configuration (overrides --preset)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument(
        "--live", action="store_true", help="run ingest, filter and workers as processes over loopback Zenoh at real speed (the filter starts globally)"
    )
    parser.add_argument("--workers", type=int, default=1, help="--live: NeRF worker processes")
    parser.add_argument("--logs", type=Path, default=Path("out/eval_tracking_live"), help="--live: folder for the services' configs and logs")
    parser.add_argument("--plots", type=Path, default=None, help="folder for the PNG figure")
    parser.add_argument("--json", action="store_true", help="print the report and the error series as JSON")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_poses_argument(parser)
    parser.set_defaults(func=run)


def localizer_config(args: argparse.Namespace) -> LocalizerConfig:
    """--config, else --preset; recovery turned off if --no-recovery, the depth term if --no-depth."""
    config = without_depth(load_config(args.config) if args.config is not None else preset(args.preset), args.no_depth)
    if args.no_recovery:
        config = config.model_copy(update={"recovery": config.recovery.model_copy(update={"enabled": False})})
    return config


def camera_path(args: argparse.Namespace, radiance_map: RadianceMap) -> CameraPath:
    """The figure-eight in the world, or the sequence folder replayed at the nominal speed."""
    if args.sequence == WORLD:
        if not isinstance(radiance_map, ProceduralWorld):
            raise LocnerfInputError(f"--sequence world needs --map world (got --map {args.map}): the synthetic images come from the procedural world")
        return WorldPath(radiance_map, FigureEightTrajectory(), CameraConfig())
    folder = Path(args.sequence)
    if not folder.is_dir():
        raise FileNotFoundError(f"--sequence {folder}: no such folder (expected 'world' or a data-set folder)")
    colour_camera = map_colour_camera(radiance_map)
    return read_sequence_path(
        folder,
        args.split,
        args.downscale,
        args.speed,
        args.odom_rate,
        args.background,
        args.frame_rate,
        colour_camera,
        passes=args.passes,
        poses=check_map_poses(radiance_map, args.poses),
        lens=map_lens(radiance_map),
    )


def convergence_criterion(args: argparse.Namespace) -> ConvergenceConfig:
    """--converged-translation/-rotation/-hold, checked before any work starts."""
    if args.converged_translation <= 0 or args.converged_rotation <= 0 or args.converged_hold < 0:
        raise LocnerfInputError(
            f"--converged-translation {args.converged_translation}, --converged-rotation {args.converged_rotation}, "
            f"--converged-hold {args.converged_hold}: expected positive thresholds and a hold of 0 s or more"
        )
    return ConvergenceConfig(translation=args.converged_translation, rotation_deg=args.converged_rotation, hold=args.converged_hold)


def back_on_track_criterion(args: argparse.Namespace) -> ConvergenceConfig:
    """--back-on-track, else :data:`BACK_ON_TRACK`."""
    if args.back_on_track is None:
        return BACK_ON_TRACK
    fields = ("translation", "rotation_deg", "hold")
    return from_flags(ConvergenceConfig, dict(zip(fields, args.back_on_track)), dict.fromkeys(fields, "--back-on-track"))


def vio_config(args: argparse.Namespace) -> VioConfig:
    """The odometry model of --odom-rate, --drift, --yaw-drift, --noise, --rotation-noise."""
    values = {
        "rate": args.odom_rate,
        "translation_drift": args.drift,
        "yaw_drift_rate": math.radians(args.yaw_drift),
        "translation_noise": args.noise,
        "rotation_noise": math.radians(args.rotation_noise),
    }
    flags = {
        "rate": "--odom-rate",
        "translation_drift": "--drift",
        "yaw_drift_rate": "--yaw-drift (in radians)",
        "translation_noise": "--noise",
        "rotation_noise": "--rotation-noise (in radians)",
    }
    return from_flags(VioConfig, values, flags)


def with_kidnap_jump(args: argparse.Namespace, path: CameraPath, scenario_config: ScenarioConfig) -> tuple[ScenarioConfig, KidnapJump | None]:
    """The scenario with ``--kidnap-jump``'s shift (also left in ``args.kidnap_shift`` for the live ingest), and the jump; unchanged without it."""
    if args.kidnap_jump is None:
        return scenario_config, None
    jump = kidnap_shift_for_jump(path, args.kidnap_at, args.odom_rate, *args.kidnap_jump)
    args.kidnap_shift = jump.shift
    return scenario_config.model_copy(update={"kidnap_shift": jump.shift}), jump


def kidnap_jump_report(jump: KidnapJump | None) -> dict[str, float]:
    """The chosen jump for the report (empty without ``--kidnap-jump``)."""
    return {} if jump is None else {"kidnap_shift_s": jump.shift, "kidnap_jump_m": jump.distance, "kidnap_jump_deg": jump.angle_deg}


def run(args: argparse.Namespace) -> int:
    image_rate = args.image_rate if args.image_rate is not None else (5.0 if args.live else 3.0)
    if args.odom_rate <= 0 or image_rate <= 0:
        raise LocnerfInputError(f"--odom-rate {args.odom_rate}, --image-rate {image_rate}: expected positive rates")
    criterion = convergence_criterion(args)
    scenario_config = from_flags(
        ScenarioConfig, {"duration": args.duration, "image_rate": image_rate, "vio": vio_config(args), "kidnap_at": args.kidnap_at, "seed": args.seed}
    )
    bag = args.sequence != WORLD and is_bag(args.sequence)
    if bag and args.kidnap_at is not None:
        raise LocnerfInputError(f"--kidnap-at with the bag {args.sequence}: a bag's camera moved as recorded, it cannot be kidnapped")
    if args.kidnap_jump is not None and args.kidnap_at is None:
        raise LocnerfInputError(f"--kidnap-jump {args.kidnap_jump[0]} {args.kidnap_jump[1]} without --kidnap-at: expected the time of the kidnapping too")
    if args.kidnap_at is not None and args.odometry not in (SYNTHETIC, RGBD):
        raise LocnerfInputError(
            f"--kidnap-at with --odometry {args.odometry}: a recorded trajectory follows the recorded camera and cannot see the simulated jump;"
            " expected --odometry synthetic, or rgbd (computed from the frames the kidnapped camera delivers)"
        )
    args.kidnap_shift = None
    if args.live:
        if args.background != "white" or args.init != "global" or args.no_recovery or args.plots:
            raise LocnerfInputError("--live: --background white, --init global, no --no-recovery and no --plots (the services do not do the others)")
        jump = None
        if bag:
            sensor_seconds = bag_extent(args.sequence)[0]
        else:
            path = camera_path(args, open_map(args.map, torch.device("cpu")))
            scenario_config, jump = with_kidnap_jump(args, path, scenario_config)
            check_timeline(path, scenario_config)
            sensor_seconds = args.duration if args.duration is not None else path.duration
        report = run_live(args, criterion, image_rate, vio_config(args).model_dump(), sensor_seconds, back_on_track_criterion(args)) | kidnap_jump_report(jump)
        print(json.dumps(report) if args.json else json.dumps(report, indent=2))
        return 0
    device = resolve_device(args.device)
    radiance_map = open_map(args.map, device)
    jump = None
    if bag:
        scenario = bag_scenario(args.sequence, radiance_map.normalization)
    else:
        path = camera_path(args, radiance_map)
        scenario_config, jump = with_kidnap_jump(args, path, scenario_config)
        track = eval_tracking_odometry.offline_track(args, path, scenario_config, map_colour_camera(radiance_map))
        scenario = build_scenario(path, scenario_config, radiance_map.normalization, track=track)
    config = localizer_config(args)
    region = search_region(radiance_map) if config.recovery.enabled else None
    keyframes = recovery_keyframes(config, radiance_map, scenario.path.intrinsics, args.seed + 2)
    localizer = Localizer(config, torch.Generator().manual_seed(args.seed), device, region=region, keyframes=keyframes)
    image_generator = torch.Generator().manual_seed(args.seed + 1)
    record = run_tracking(
        scenario, radiance_map, localizer, StartConfig(mode=args.init), image_generator, show_progress=not args.quiet, updates_per_image=args.updates_per_image
    )
    summary = (
        summarize_tracking(record, criterion, back_on_track_criterion(args))
        | eval_tracking_odometry.scenario_odometry(args, scenario, None if bag else track)
        | kidnap_jump_report(jump)
    )
    if args.plots is not None:
        name = "world" if args.sequence == WORLD else Path(args.sequence).name
        figure = plot_tracking_errors(record, convergence_stamps(summary), criterion, args.plots / "tracking_error.png", f"tracking: {name}")
        summary["plot"] = str(figure)
    valid = scenario.odometry_valid if scenario.odometry_valid is not None else torch.ones(len(scenario.stamps), dtype=torch.bool)
    camera_odometry = scenario.odometry @ scenario.path.T_body_cam
    summary = eval_tracking_odometry.write_outputs(args, summary, record, radiance_map.normalization, criterion, scenario.stamps[valid], camera_odometry[valid])
    if args.json:
        print(json.dumps({**summary, "series": error_series(record)}))
    else:
        print(json.dumps(summary, indent=2))
    return 0
