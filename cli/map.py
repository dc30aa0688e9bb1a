"""``locnerf map build|eval|ceiling|depth-offset|score-trials|render|compare|add-surface-distance|prune|info``: build a map from posed images, measure it, look at it."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import cv2
import numpy as np
import torch

from locnerf.config import load_config
from locnerf.data import read_dataset
from locnerf.data.colour_camera import read_on_map_camera, sfm_training_frames
from locnerf.data.sfm_poses import check_pose_source
from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.eval.depth_agreement import ColourPeak, depth_agreement
from locnerf.eval.plots import plot_images_beside_renders
from locnerf.eval.reprojection_ceiling import CeilingConfig, reprojection_ceiling
from locnerf.eval.trial_renders import read_trials_report, score_trial_renders
from locnerf.field.grid import GridFieldConfig
from locnerf.field.grid_map import GridMap
from locnerf.field.map_file import load_map, read_map_info, save_map
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import load_nerf_pytorch_checkpoint
from locnerf.field.surface_distance import SurfaceDistanceConfig
from locnerf.render.image import render_image
from locnerf.train import BuildConfig, RoomConfig, build_map, evaluate_held_out, psnr
from locnerf.train.surface_layer import surface_distance_of_frames
from locnerf_cli.flags import add_poses_argument, from_flags
from locnerf_cli.map_sfm import add_align_command, add_sfm_arguments, posed_capture_of_args

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf map`` and its sub-subcommands."""
    commands = parser.add_subparsers(dest="map_command", required=True)

    build = commands.add_parser("build", help="build a map file from a data set (LLFF, NeRF-synthetic, nerfstudio, 7-Scenes)")
    build.add_argument("data", help="data-set folder; with --sfm a capture: image folder, video, RGB-D data set, COLMAP model or transforms.json")
    build.add_argument("--out", required=True, help="map file to write")
    build.add_argument("--backend", choices=("grid", "nerf_pytorch"), default="grid", help="grid: train a grid map; nerf_pytorch: import --checkpoint")
    build.add_argument("--checkpoint", help="nerf-pytorch .tar checkpoint (backend nerf_pytorch)")
    build.add_argument("--minutes", type=float, default=10.0, help="training wall-time budget")
    build.add_argument("--steps", type=int, default=BuildConfig().steps, help="most training steps")
    build.add_argument("--voxels", type=int, help=f"grid vertices in all (default {GridFieldConfig().voxels}; RGB-D data {RoomConfig().voxels})")
    build.add_argument("--downscale", type=int, help="image size divisor (default 8 for LLFF, 4 for 7-Scenes, 1 otherwise)")
    build.add_argument(
        "--split", default="train", help="split to build from (recorded in the map; the held-out figures use the test split's frames it did not train on)"
    )
    build.add_argument("--stride", type=int, default=1, help="keep every N-th frame of the split")
    build.add_argument("--no-depth", action="store_true", help="build from colour only even when the data set has depth images")
    build.add_argument(
        "--no-colour-calibration",
        action="store_true",
        help="RGB-D data posed at the depth camera (7-Scenes): keep the colour rays at the depth camera's pose instead of calibrating the colour camera",
    )
    build.add_argument(
        "--depth-weight", type=float, help=f"weight of the expected-depth loss (RGB-D data; default {RoomConfig().depth_weight}, as BuildConfig.room)"
    )
    build.add_argument("--device", default="auto", help="auto | cpu | cuda[:N]")
    build.add_argument("--seed", type=int, default=0)
    add_poses_argument(build)
    add_sfm_arguments(build)
    build.set_defaults(func=run_build)

    evaluate = commands.add_parser("eval", help="PSNR/SSIM of a map against a data set's views")
    evaluate.add_argument("map", help="map file")
    evaluate.add_argument("data", nargs="?", help="data-set folder (or --data)")
    evaluate.add_argument("--data", dest="data_option", help="data-set folder (instead of the positional argument)")
    evaluate.add_argument("--split", default="test", help="views to score; those the map was built from are scored apart, as train-set figures")
    evaluate.add_argument("--downscale", type=int)
    evaluate.add_argument("--stride", type=int, default=1, help="evaluate every N-th view of the split")
    evaluate.add_argument("--device", default="auto")
    evaluate.add_argument("--json", action="store_true", help="print JSON")
    add_poses_argument(evaluate)
    evaluate.set_defaults(func=run_eval)

    trials = commands.add_parser(
        "score-trials",
        help="PSNR/SSIM of each trial of a `locnerf eval single-image|global --json` report, rendered from where it ended and from its "
        "ground truth: does the map itself prefer the estimate where a trial failed?",
    )
    trials.add_argument("map", help="the map file the report was measured on")
    trials.add_argument("report", type=Path, help="JSON report of locnerf eval single-image|global --json")
    trials.add_argument("--data", required=True, help="the report's data-set folder")
    trials.add_argument("--split", default="test", help="the split the report's views come from")
    trials.add_argument("--downscale", type=int)
    trials.add_argument("--device", default="auto")
    trials.add_argument("--json", action="store_true", help="print JSON")
    add_poses_argument(trials)
    trials.set_defaults(func=run_score_trials)

    render = commands.add_parser("render", help="render one view of a map to a PNG")
    which = render.add_mutually_exclusive_group(required=True)
    which.add_argument("--view", type=int, help="index of a reference (training) pose")
    which.add_argument("--pose", help=".npy or text file with a 4x4 camera-to-world pose (OpenGL axes, map frame)")
    render.add_argument("map", help="map file")
    render.add_argument("--out", required=True, help="PNG to write")
    render.add_argument("--device", default="auto")
    render.set_defaults(func=run_render)

    compare = commands.add_parser("compare", help="PNG of a split's camera images beside the map's renders at their true poses")
    compare.add_argument("map", help="map file")
    compare.add_argument("--data", required=True, help="data-set folder")
    compare.add_argument("--split", default="test")
    compare.add_argument("--downscale", type=int)
    compare.add_argument("--views", type=int, default=4, help="views, evenly spaced over the split")
    compare.add_argument("--out", required=True, help="PNG to write")
    compare.add_argument("--device", default="auto")
    compare.set_defaults(func=run_compare)

    ceiling = commands.add_parser(
        "ceiling", help="RGB-D data: how well the training frames, re-projected through each held-out view's own depth, explain it, beside the map"
    )
    add_map_and_frames_arguments(ceiling, "map file", "RGB-D data-set folder (7-Scenes)", "test", "held-out split")
    ceiling.add_argument("--train-split", default="train", help="the split the map was built from")
    ceiling.add_argument("--stride", type=int, default=10, help="every N-th held-out view")
    ceiling.add_argument("--candidates", type=int, default=CeilingConfig().candidates, help="training frames tried per view (nearest first)")
    ceiling.add_argument("--device", default="auto")
    ceiling.add_argument("--json", action="store_true", help="print JSON (per view and summary)")
    add_poses_argument(ceiling)
    ceiling.set_defaults(func=run_ceiling)

    offset = commands.add_parser(
        "depth-offset", help="RGB-D map with a surface-distance layer: how far each frame's own depth, fitted to the layer from its true pose, moves it"
    )
    add_map_and_frames_arguments(
        offset,
        "map file with a surface-distance layer",
        "RGB-D data-set folder (7-Scenes)",
        "test",
        "the frames to fit (train: the frames the layer was built from)",
    )
    offset.add_argument("--stride", type=int, default=10, help="every N-th frame")
    offset.add_argument("--points", type=int, default=4000, help="depth readings per frame")
    offset.add_argument("--seed", type=int, default=0, help="seeds the readings drawn")
    offset.add_argument("--colour", metavar="CONFIG", help="also the colour term's best pose near the truth, with this localizer file's measurement")
    offset.add_argument("--json", action="store_true", help="print JSON (per frame and summary)")
    add_poses_argument(offset)
    offset.set_defaults(func=run_depth_offset)

    layer = commands.add_parser(
        "add-surface-distance", help="add (or replace) a map's surface-distance layer from the depth images it was built from (RGB-D data)"
    )
    add_map_and_frames_arguments(
        layer, "map file (rewritten in place unless --out)", "RGB-D data-set folder the map was built from", "train", "the split the map was built from"
    )
    layer.add_argument("--voxel", type=float, default=SurfaceDistanceConfig().voxel, help="vertex spacing, map units")
    layer.add_argument("--truncation", type=float, default=SurfaceDistanceConfig().truncation, help="largest stored distance, map units")
    layer.add_argument("--out", help="map file to write (default: MAP)")
    layer.set_defaults(func=run_add_surface_distance)

    prune = commands.add_parser("prune", help="re-threshold a grid map's occupancy (faster renders, slightly lower PSNR)")
    prune.add_argument("map", help="grid map file (rewritten in place unless --out)")
    prune.add_argument("--occupancy-alpha", type=float, required=True, help="one-step opacity below which voxels are skipped")
    prune.add_argument("--out", help="map file to write (default: MAP)")
    prune.set_defaults(func=run_prune)

    info = commands.add_parser("info", help="describe a map file")
    info.add_argument("map", help="map file")
    info.set_defaults(func=run_info)

    add_align_command(commands)


def add_map_and_frames_arguments(parser: argparse.ArgumentParser, map_help: str, data_help: str, split: str, split_help: str) -> None:
    """The positional map and the frames a command reads of a data set: ``--data``, ``--split`` (default ``split``), ``--downscale``."""
    parser.add_argument("map", help=map_help)
    parser.add_argument("--data", required=True, help=data_help)
    parser.add_argument("--split", default=split, help=split_help)
    parser.add_argument("--downscale", type=int)


def _split_on_map_camera(radiance_map, data: str, downscale: int | None, split: str = "test", stride: int = 1, poses: str = "dslam"):
    """The frames of ``split`` (held-out views, or the training frames) posed by ``poses`` on the camera the map was built for (:func:`read_on_map_camera`)."""
    return read_on_map_camera(data, radiance_map, poses, split=split, downscale=downscale, skip_missing=True, stride=stride)


def _training_frames(args: argparse.Namespace):
    """The frames ``map build`` trains on, and the map metadata of their pose source: with ``--poses sfm``
    the SfM colour-camera poses, the depth camera placed by the colour camera calibrated on the dSLAM poses
    (the Kinect's own offset; :func:`sfm_training_frames`); with ``--sfm``, the capture posed by structure from motion."""
    if args.sfm:
        return posed_capture_of_args(args)
    if check_pose_source(args.poses) == "dslam":
        return read_dataset(args.data, split=args.split, downscale=args.downscale, stride=args.stride), {}
    return sfm_training_frames(args.data, args.split, args.downscale, args.stride, calibrate=not args.no_colour_calibration)


def run_build(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    train, pose_metadata = _training_frames(args)
    if args.backend == "nerf_pytorch":
        if not args.checkpoint:
            raise LocnerfInputError("--backend nerf_pytorch needs --checkpoint FILE.tar")
        info = MapInfo(train.normalization, train.intrinsics, train.T_world_cam.double(), {"source": train.source, "checkpoint": args.checkpoint})
        radiance_map = load_nerf_pytorch_checkpoint(args.checkpoint, info, train.white_background, device)
    else:
        field = GridFieldConfig() if args.voxels is None else from_flags(GridFieldConfig, {"voxels": args.voxels})
        values = {
            "steps": args.steps,
            "minutes": args.minutes,
            "seed": args.seed,
            "field": field,
            "use_depth": not args.no_depth,
            "calibrate_colour_camera": not args.no_colour_calibration,
            **({} if args.depth_weight is None else {"depth_weight": args.depth_weight}),
        }
        config = from_flags(BuildConfig, values, {"use_depth": "--no-depth", "calibrate_colour_camera": "--no-colour-calibration"})
        radiance_map = build_map(train, config, device=device, progress=True)
    radiance_map.metadata.update(pose_metadata)
    radiance_map.metadata.update(train_split=args.split, train_stride=args.stride, train_views=len(train))
    if not args.sfm:  # an SfM map's frame is not the data set's: the data set's poses cannot score it
        test_views = _split_on_map_camera(radiance_map, args.data, args.downscale, poses=args.poses)
        scores = evaluate_held_out(radiance_map.render_rays, test_views, radiance_map.reference_poses(), device)
        radiance_map.metadata.update(**_score_metadata(scores, args.split))
    save_map(radiance_map, args.out)
    print(json.dumps({"out": str(args.out), **radiance_map.metadata}, default=str))
    return 0


def _score_metadata(scores: dict, split: str) -> dict:
    """Map metadata of :func:`evaluate_held_out`'s scores of the test split: ``heldout_*`` over the views the
    map did not train on, ``train_frames_*`` (train-set figures, not held out) over those it did."""
    metadata = {"heldout_views": scores["views"]}
    if scores["views"]:
        metadata.update(heldout_psnr=round(scores["psnr"], 3), heldout_ssim=round(scores["ssim"], 4))
    if "training_frames" in scores:
        trained = scores["training_frames"]
        logger.warning(
            "map build: %d of the test split's views are frames the map was built from (--split %s); their scores are "
            "recorded as train_frames_psnr/ssim (train-set figures, not held out)",
            trained["views"],
            split,
        )
        metadata.update(train_frames_psnr=round(trained["psnr"], 3), train_frames_ssim=round(trained["ssim"], 4), train_frames_views=trained["views"])
    return metadata


def run_eval(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    if (args.data is None) == (args.data_option is None):
        raise LocnerfInputError("map eval: name the data set once, as DATA or --data DATA")
    radiance_map = load_map(args.map, device)
    views = _split_on_map_camera(radiance_map, args.data or args.data_option, args.downscale, args.split, args.stride, args.poses)
    scores = evaluate_held_out(radiance_map.render_rays, views, radiance_map.reference_poses(), device)
    if args.json:
        print(json.dumps(scores))
        return 0
    if scores["views"]:
        print(f"held-out PSNR {scores['psnr']:.2f} dB  SSIM {scores['ssim']:.4f}  over {scores['views']} views")
    if "training_frames" in scores:
        trained = scores["training_frames"]
        print(f"train-set PSNR (not held out) {trained['psnr']:.2f} dB  SSIM {trained['ssim']:.4f}  over {trained['views']} views the map was built from")
    return 0


def run_score_trials(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    trials = read_trials_report(args.report)
    radiance_map = load_map(args.map, device)
    views = _split_on_map_camera(radiance_map, args.data, args.downscale, args.split, poses=args.poses)
    scores = score_trial_renders(radiance_map.render_rays, views, trials, device)
    if args.json:
        print(json.dumps(scores))
        return 0
    for row in scores["trials"]:
        print(
            f"{row['name']}  {'success' if row['success'] else 'failure'}  off by {row['translation_error']:.3f} (truth units) and {row['rotation_error_deg']:.2f} deg  "
            f"PSNR from the estimate {row['psnr_estimate']:.2f} dB, from the truth {row['psnr_truth']:.2f} dB"
        )
    for kind in ("failures", "successes"):
        if scores[kind] is not None:
            summary = scores[kind]
            print(
                f"{kind}: {summary['trials']}, PSNR(estimate) - PSNR(truth) median {summary['psnr_gain_median_db']:.2f} dB "
                f"({summary['psnr_gain_min_db']:.2f} to {summary['psnr_gain_max_db']:.2f}), the estimate renders better in {summary['estimate_renders_better']}"
            )
    return 0


def _read_pose(path: str) -> torch.Tensor:
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"pose file {file}: no such file")
    pose = np.load(file) if file.suffix == ".npy" else np.loadtxt(file)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise LocnerfInputError(f"pose file {file}: expected a finite 4x4 matrix, got shape {pose.shape}")
    return torch.from_numpy(pose)


def run_render(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    radiance_map = load_map(args.map, device)
    if args.pose:
        pose = _read_pose(args.pose)
    else:
        poses = radiance_map.reference_poses()
        if not 0 <= args.view < len(poses):
            raise LocnerfInputError(f"--view {args.view}: expected 0..{len(poses) - 1}")
        pose = poses[args.view]
    image = render_image(radiance_map.render_rays, pose.to(device, torch.float32), radiance_map.default_intrinsics)
    pixels = (image.cpu().numpy() * 255.0 + 0.5).astype(np.uint8)[:, :, ::-1]
    if not cv2.imwrite(str(args.out), pixels):
        raise LocnerfInputError(f"--out {args.out}: cannot write a PNG there")
    print(args.out)
    return 0


def run_compare(args: argparse.Namespace) -> int:
    if args.views < 1:
        raise LocnerfInputError(f"--views {args.views}: expected >= 1")
    device = resolve_device(args.device)
    radiance_map = load_map(args.map, device)
    views = _split_on_map_camera(radiance_map, args.data, args.downscale, args.split)
    panels = []
    for position in np.linspace(0, len(views) - 1, args.views).round().astype(int).tolist():
        rendering = render_image(radiance_map.render_rays, views.T_world_cam[position].to(device, torch.float32), views.intrinsics).cpu()
        panels.append((f"{views.names[position]} ({psnr(rendering, views.images[position]):.1f} dB)", views.images[position], rendering))
    title = f"{Path(args.map).name} on the {args.split} split: camera image | map rendered at the true pose"
    print(plot_images_beside_renders(panels, Path(args.out), title, render_heading="map at the true pose"))
    return 0


def run_ceiling(args: argparse.Namespace) -> int:
    if args.candidates < 1:
        raise LocnerfInputError(f"--candidates {args.candidates}: expected >= 1")
    device = resolve_device(args.device)
    radiance_map = load_map(args.map, device)
    views = _split_on_map_camera(radiance_map, args.data, args.downscale, args.split, args.stride, args.poses)
    training = _split_on_map_camera(radiance_map, args.data, args.downscale, args.train_split, poses=args.poses)
    report = reprojection_ceiling(views, training, radiance_map.render_rays, CeilingConfig(candidates=args.candidates))
    if args.json:
        print(json.dumps(report))
    else:
        for row in report["views"]:
            logger.info("%s", "  ".join(f"{key} {value:.3f}" if isinstance(value, float) else f"{key} {value}" for key, value in row.items()))
        print("  ".join(f"{key} {value:.3f}" if isinstance(value, float) else f"{key} {value}" for key, value in report["summary"].items()))
    return 0


def run_depth_offset(args: argparse.Namespace) -> int:
    radiance_map = load_map(args.map, "cpu")
    if radiance_map.surface_distance is None:
        raise LocnerfInputError(f"map {args.map}: no surface-distance layer; `locnerf map add-surface-distance` adds one from the depth images")
    frames = _split_on_map_camera(radiance_map, args.data, args.downscale, args.split, args.stride, args.poses)
    colour = ColourPeak(radiance_map.render_rays, load_config(args.colour).measurement) if args.colour else None
    report = depth_agreement(frames, radiance_map.surface_distance, points=args.points, seed=args.seed, colour=colour)
    if args.json:
        print(json.dumps(report))
    else:
        for row in report["frames"]:
            logger.info("%s  translation %.4f m  rotation %.3f°", row["name"], row["translation_m"], row["rotation_deg"])
        print("  ".join(f"{key} {value:.4f}" if isinstance(value, float) else f"{key} {value}" for key, value in report["summary"].items()))
    return 0


def run_add_surface_distance(args: argparse.Namespace) -> int:
    radiance_map = load_map(args.map, "cpu")
    frames = _split_on_map_camera(radiance_map, args.data, args.downscale, args.split)
    config = from_flags(SurfaceDistanceConfig, {"voxel": args.voxel, "truncation": args.truncation})
    radiance_map.surface_distance = surface_distance_of_frames(frames, config)
    save_map(radiance_map, args.out or args.map)
    print(json.dumps({"out": args.out or args.map, "vertices": list(radiance_map.surface_distance.shape), **config.model_dump()}))
    return 0


def run_prune(args: argparse.Namespace) -> int:
    radiance_map = load_map(args.map, "cpu")
    if not isinstance(radiance_map, GridMap):
        raise LocnerfInputError(f"map {args.map}: prune applies to grid maps, this one is {radiance_map.kind}")
    fraction = radiance_map.field.update_occupancy(args.occupancy_alpha)
    radiance_map.metadata["occupancy_alpha"] = args.occupancy_alpha
    save_map(radiance_map, args.out or args.map)
    print(json.dumps({"out": args.out or args.map, "occupied_fraction": fraction}))
    return 0


def run_info(args: argparse.Namespace) -> int:
    archive, info = read_map_info(args.map)
    summary = {
        "kind": archive["kind"],
        "version": archive["version"],
        "normalization": info.normalization.model_dump(mode="json"),
        "intrinsics": info.intrinsics.model_dump(mode="json"),
        "reference_views": int(info.reference_poses.shape[0]),
        "metadata": info.metadata,
    }
    print(json.dumps(summary, indent=2, default=str))
    return 0
