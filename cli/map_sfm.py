"""``locnerf map build CAPTURE --sfm`` (the flags that pose a capture by structure from motion and fix its scale and up axis) and ``locnerf map align``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from locnerf.data import read_dataset
from locnerf.data.posed_images import PosedImages
from locnerf.data.sfm_poses import POSES_METADATA_KEY
from locnerf.errors import LocnerfInputError
from locnerf.field.map_file import load_map, save_map
from locnerf.sfm.alignment import FRAMES_KEY, aligned_normalization, alignment_errors, truth_of_frames
from locnerf.sfm.pipeline import DEPTH_CAMERA_PLACEMENTS, MetricOptions, posed_capture
from locnerf.sfm.reconstruct import SfmConfig
from locnerf_cli.flags import from_flags


def add_sfm_arguments(build: argparse.ArgumentParser) -> None:
    """``--sfm`` and its options on ``map build``."""
    group = build.add_argument_group("structure from motion (--sfm)")
    group.add_argument(
        "--sfm",
        action="store_true",
        help="pose DATA by structure from motion (pycolmap, CPU): an image folder, a video, or an RGB-D data set whose pose files are not read; "
        "a COLMAP sparse model or a transforms.json is taken as it is",
    )
    group.add_argument("--scale", type=float, help="metres per SfM unit (a scale known otherwise)")
    group.add_argument(
        "--known-distance",
        nargs=3,
        metavar=("FRAME_A", "FRAME_B", "METRES"),
        help="the distance between two frames' camera centres (frame name, stem or position)",
    )
    group.add_argument(
        "--up", nargs=3, type=float, metavar=("X", "Y", "Z"), help="up in the first posed image's camera frame, OpenCV axes (level camera: 0 -1 0)"
    )
    group.add_argument(
        "--trajectory", help="TUM trajectory (odometry/VIO, metres, z up) recorded with the capture: scale and gravity by a similarity fit by stamp"
    )
    group.add_argument("--no-depth-scale", action="store_true", help="do not take the scale from the capture's depth images")
    group.add_argument(
        "--depth-camera",
        choices=DEPTH_CAMERA_PLACEMENTS,
        default="colour",
        help="an RGB-D capture's depth camera: at the colour camera (default), from the SfM points against the depth images (points),"
        " or by the grey values of depth points across the colour images (photometric); docs/MAPS.md",
    )
    group.add_argument("--sfm-features", type=int, help=f"most SIFT features per image (default {SfmConfig().max_features})")
    group.add_argument("--sfm-camera", help=f"COLMAP camera model (default {SfmConfig().camera_model})")
    group.add_argument("--vocab-tree", help="COLMAP vocabulary-tree file: enables loop detection in sequential matching")
    group.add_argument("--sfm-cache", help="folder of cached SfM results (default: OUT.sfm beside the map)")


def posed_capture_of_args(args: argparse.Namespace) -> tuple[PosedImages, dict]:
    """The posed images and map metadata of ``map build --sfm``'s arguments."""
    metric = from_flags(
        MetricOptions,
        {
            "scale": args.scale,
            "known_distance": None if args.known_distance is None else (args.known_distance[0], args.known_distance[1], float(args.known_distance[2])),
            "up": None if args.up is None else tuple(args.up),
            "trajectory": args.trajectory,
            "depth": not args.no_depth_scale,
        },
        {"known_distance": "--known-distance", "depth": "--no-depth-scale"},
    )
    values = {"max_features": args.sfm_features, "camera_model": args.sfm_camera, "vocab_tree": args.vocab_tree, "seed": args.seed}
    sfm = from_flags(SfmConfig, {key: value for key, value in values.items() if value is not None})
    cache = Path(args.sfm_cache) if args.sfm_cache else Path(f"{args.out}.sfm")
    return posed_capture(args.data, cache, metric, sfm, downscale=args.downscale, stride=args.stride, split=args.split, depth_camera=args.depth_camera)


def add_align_command(commands: argparse._SubParsersAction) -> None:
    """``map align``: score an SfM map's cameras against a ground truth after one similarity, and write a copy aligned to it."""
    align = commands.add_parser(
        "align", help="SfM maps: fit one similarity from the map's cameras to a data set's poses of the same frames, report each camera's error after it"
    )
    align.add_argument("map", help="map built with map build --sfm")
    align.add_argument("--data", required=True, help="data set holding the ground truth of the map's frames")
    align.add_argument("--split", default="train", help="the split the map was built from")
    align.add_argument("--poses", default="dslam", help="7-Scenes ground truth: dslam or sfm (pgt_sfm/: the colour camera's poses, as SfM estimates)")
    align.add_argument("--out", help="write a copy of the map whose frame is the ground truth's (for the eval commands, with --poses)")
    align.add_argument("--json", action="store_true", help="print every camera's error too")
    align.set_defaults(func=run_align)


def run_align(args: argparse.Namespace) -> int:
    radiance_map = load_map(args.map, "cpu")
    names = (radiance_map.metadata.get("sfm") or {}).get(FRAMES_KEY)
    if not names:
        raise LocnerfInputError(f"map {args.map}: no sfm.{FRAMES_KEY} in its metadata; expected a map built with map build --sfm")
    truth = read_dataset(args.data, split=args.split, poses=args.poses)
    shared, truth_poses = truth_of_frames(names, truth.names, truth.T_world_cam)
    similarity, report = alignment_errors(radiance_map.reference_poses().double().numpy()[shared], truth_poses)
    record = {"data": args.data, "split": args.split, "poses": args.poses, **report["summary"]}
    if args.out:
        radiance_map.info.normalization = aligned_normalization(radiance_map.normalization, similarity, truth.normalization)
        radiance_map.metadata.update(aligned_to=record, **{POSES_METADATA_KEY: args.poses})
        save_map(radiance_map, args.out)
    print(json.dumps({**record, **({"frames": [names[i] for i in shared], **report} if args.json else {})}))
    return 0
