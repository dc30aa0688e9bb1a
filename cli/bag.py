"""``locnerf bag``: describe a ROS 2 bag, and write a data set as one.

``bag info BAG`` lists each topic's type, message count, rate and time span. ``bag export DATA --out
BAG`` writes a data set the product reads (7-Scenes, LLFF, NeRF-synthetic, nerfstudio, EuRoC) as an
MCAP rosbag2 with the standard message types (docs/BAGS.md): the very stream the folder's replay
sends (``locnerf eval tracking --live`` for a sequence folder, ``source = "euroc"`` for EuRoC), its
odometry simulated from the ground truth with the same model and seed, or for a sequence folder the
replay's real odometry (``--odometry rgbd`` or a TUM / EuRoC trajectory FILE, as ``eval tracking``).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path

import torch
from tqdm import tqdm

from locnerf.bags.reader import summarize
from locnerf.bags.writer import BagWriter, EventWriter
from locnerf.data.colour_camera import check_map_poses, map_colour_camera
from locnerf.data.euroc import read_euroc
from locnerf.data.map_lens import map_lens
from locnerf.errors import LocnerfInputError
from locnerf.maps.source import open_map
from locnerf.odometry.sequence import SYNTHETIC
from locnerf_cli import eval_tracking_odometry
from locnerf_cli.eval_tracking import vio_config
from locnerf_cli.eval_tracking_live import scenario_settings
from locnerf_cli.flags import add_poses_argument
from locnerf_cli.tracking_flags import add_odometry_arguments
from locnerf_services.sensor_ingest.euroc_source import EurocSourceConfig, euroc_events
from locnerf_services.sensor_ingest.scenario_source import ScenarioSourceConfig, scenario_events

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    commands = parser.add_subparsers(dest="bag_command", required=True)
    info = commands.add_parser("info", help="topics of a bag: type, count, rate, time span")
    info.add_argument("bag", type=Path, help="rosbag2 folder, or an .mcap / .db3 file")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(func=run_info)

    export = commands.add_parser("export", help="write a data set as an MCAP bag (Odometry, Image, CameraInfo, depth, ground truth)")
    export.add_argument("data", type=Path, help="data-set folder: 7-Scenes, LLFF, NeRF-synthetic, nerfstudio, or EuRoC (holding mav0/)")
    export.add_argument("--out", type=Path, required=True, help="the bag folder to create (must not exist)")
    export.add_argument("--split", default="test", help="sequence folder: the split to write")
    export.add_argument("--downscale", type=int, default=None, help="image size divisor (default: the data set's; EuRoC 1)")
    export.add_argument("--speed", type=float, default=0.66, help="sequence folder: nominal camera speed, metres per second")
    export.add_argument("--frame-rate", type=float, default=None, help="sequence folder: the capture's frame rate (7-Scenes: 30), instead of --speed")
    export.add_argument("--duration", type=float, default=None, help="sequence folder: seconds (default: one loop)")
    export.add_argument("--image-rate", type=float, default=5.0, help="sequence folder: images per second")
    export.add_argument("--camera", default="cam0", help="EuRoC: camera folder under mav0/")
    add_odometry_arguments(export)
    eval_tracking_odometry.add_source_arguments(export)
    export.add_argument(
        "--map",
        default=None,
        help="the map the bag is for: the poses move onto its colour camera (7-Scenes: the map built with a calibrated colour camera), "
        "and the colour images are resampled through the lens an SfM-built map records onto its camera, as its queries are",
    )
    add_poses_argument(export)
    export.add_argument("--compression", choices=("", "png", "jpeg"), default="", help="colour images as CompressedImage (default: raw rgb8 Image)")
    export.add_argument("--seed", type=int, default=0, help="seed of the odometry noise (and image noise), as the replay's")
    export.add_argument("--quiet", action="store_true", help="no progress bar")
    export.set_defaults(func=run_export, kidnap_at=None)


def run_info(args: argparse.Namespace) -> int:
    storage, topics = summarize(args.bag)
    rows = [
        {
            "topic": t.topic,
            "type": t.msgtype,
            "count": t.count,
            "rate_hz": None if math.isnan(t.rate_hz) else round(t.rate_hz, 3),
            "start_s": None if t.first_ns is None else t.first_ns * 1e-9,
            "end_s": None if t.last_ns is None else t.last_ns * 1e-9,
        }
        for t in topics
    ]
    if args.json:
        print(json.dumps({"bag": str(args.bag), "storage": storage, "topics": rows}))
        return 0
    print(f"bag {args.bag} ({storage}), {len(rows)} topics")
    width = max((len(row["topic"]) for row in rows), default=5)
    for row in rows:
        rate = "–" if row["rate_hz"] is None else f"{row['rate_hz']:.2f} Hz"
        span = "–" if row["start_s"] is None else f"{row['start_s']:.3f}–{row['end_s']:.3f} s ({row['end_s'] - row['start_s']:.3f} s)"
        print(f"  {row['topic']:<{width}}  {row['type']:<40} {row['count']:>7}  {rate:>10}  {span}")
    return 0


def export_events(args: argparse.Namespace):
    """The data set's sensor events, as its folder replay streams them."""
    vio = vio_config(args)
    generator = torch.Generator().manual_seed(args.seed)
    if (args.data / "mav0").is_dir():
        if args.odometry != SYNTHETIC or args.passes != 1:
            raise LocnerfInputError(f"{args.data}: a EuRoC folder is exported with its simulated odometry; --odometry and --passes are for sequence folders")
        config = EurocSourceConfig(path=str(args.data), camera=args.camera, downscale=float(args.downscale or 1), vio=vio)
        return euroc_events(read_euroc(args.data, args.camera, None), config, generator)
    radiance_map = None if args.map is None else open_map(args.map, torch.device("cpu"))
    colour_camera, lens = None, None
    if radiance_map is not None:
        check_map_poses(radiance_map, args.poses)
        colour_camera, lens = map_colour_camera(radiance_map), map_lens(radiance_map)
    replay = argparse.Namespace(**vars(args), sequence=str(args.data))
    config = ScenarioSourceConfig.model_validate(scenario_settings(replay, args.image_rate, vio.model_dump(), colour_camera, lens))  # as eval tracking --live
    return scenario_events(config, args.seed)


def run_export(args: argparse.Namespace) -> int:
    if args.out.exists():
        raise LocnerfInputError(f"--out {args.out}: exists already; expected a new folder for the bag (a bag is never overwritten)")
    events = export_events(args)
    with BagWriter(args.out) as bag:
        writer = EventWriter(bag, compression=args.compression)
        for event in tqdm(events, desc="export", unit="event", disable=args.quiet):
            writer.write(event)
    logger.info("bag %s: %s", args.out, bag.counts)
    print(json.dumps({"bag": str(args.out), "messages": bag.counts}))
    return 0
