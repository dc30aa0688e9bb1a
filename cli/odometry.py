"""``locnerf odometry DATA --split test --out FILE``: RGB-D odometry of a data set's frames as a TUM trajectory.

The frames of the split are read at the odometry's working size (7-Scenes: colour 320×240 beside
its 320×240 depth), the colour resampled onto the depth camera's grid (through the two cameras'
placement with ``--map``: the colour camera the map records, as the live runs read it), and fed in order to OpenCV's
dense RGB-D odometry (:mod:`locnerf.odometry.rgbd`), every ``--every``-th frame (2: 15 Hz of a 30 Hz
capture). Frame ``k`` of the split is stamped ``k / --frame-rate`` (7-Scenes has no stamps; this is
the clock ``locnerf eval tracking --frame-rate`` replays it on, so the file feeds ``--odometry FILE``
as it is). The file holds ``T_odom_cam`` of the depth camera (with ``--map``: of the colour camera;
locnerf's OpenGL camera axes, the first pose the identity) at every frame that did not fail; failed
frames are gaps, absent from the file.
The JSON report on stdout gives the counts, the time per frame and the drift against the data set's
own poses (aligned at the first pose; :func:`locnerf.eval.trajectory_output.odometry_drift`) and the
per-step error's statistics, the prediction noise that matches this odometry
(:func:`locnerf.odometry.step_noise.step_noise`); ``--poses sfm`` scores against 7-Scenes' SfM poses.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import cv2
import torch

from locnerf.data.colour_camera import colour_camera_of
from locnerf.data.trajectory_files import write_tum
from locnerf.errors import LocnerfInputError
from locnerf.eval.trajectory_output import odometry_drift
from locnerf.field.map_file import read_map_info
from locnerf.odometry.rgbd import RgbdOdometryConfig
from locnerf.odometry.sequence import ODOMETRY_DOWNSCALE
from locnerf.odometry.step_noise import step_noise
from locnerf.odometry.tracks import rgbd_track
from locnerf.sim.paths import read_sequence_frames
from locnerf_cli.flags import add_poses_argument

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", type=Path, help="RGB-D data-set folder (7-Scenes, TUM RGB-D)")
    parser.add_argument("--split", default="test", help="which split's frames (7-Scenes: TestSplit.txt, ...)")
    parser.add_argument("--out", type=Path, required=True, help="TUM trajectory file to write (stamp tx ty tz qx qy qz qw)")
    parser.add_argument("--kind", default="rgbd", choices=("rgbd", "rgb", "depth"), help="OpenCV variant: photometric + ICP, photometric, ICP")
    parser.add_argument("--fast", action="store_true", help="OpenCV's FAST algorithm variant")
    parser.add_argument("--frame-rate", type=float, default=30.0, help="capture rate of the frames, Hz (frame k is stamped k / rate)")
    parser.add_argument("--every", type=int, default=2, help="use every N-th frame (2: 15 Hz of a 30 Hz capture)")
    parser.add_argument("--downscale", type=int, default=ODOMETRY_DOWNSCALE, help="colour size divisor (2: 320x240 of 640x480)")
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (1: the one core the ingest gives it)")
    parser.add_argument(
        "--map",
        type=Path,
        default=None,
        help="a map built from these frames: the colour camera's placement it records (T_depth_colour) registers the colour onto the depth"
        " grid, and the file and the scores are the colour camera's",
    )
    add_poses_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.frame_rate <= 0 or args.every < 1 or args.threads < 1:
        raise LocnerfInputError(f"--frame-rate {args.frame_rate}, --every {args.every}, --threads {args.threads}: expected positive values")
    cv2.setNumThreads(args.threads)
    T_depth_colour = None
    if args.map is not None:
        T_depth_colour = colour_camera_of(read_map_info(args.map)[1].metadata)
        if T_depth_colour is None:
            raise LocnerfInputError(
                f"--map {args.map}: the map records no colour camera (T_depth_colour); expected a map built from RGB-D frames posed at the depth camera"
            )
    frames = read_sequence_frames(args.data, args.split, args.downscale, T_depth_colour=T_depth_colour, poses=args.poses)  # metric
    indices = list(range(0, len(frames), args.every))
    stamps = torch.tensor(indices, dtype=torch.float64) / args.frame_rate
    track = rgbd_track(frames, indices, stamps, RgbdOdometryConfig(kind=args.kind, fast=args.fast))
    write_tum(args.out, stamps[track.valid], track.poses[track.valid])
    truth = frames.T_world_cam.double()[indices]
    drift = odometry_drift(stamps, track.poses, track.valid, truth)
    drift.pop("series")
    noise = step_noise(track.poses, track.valid, truth)
    report = {"out": str(args.out), "data": str(args.data), "split": args.split, "poses": args.poses, "map": None if args.map is None else str(args.map)}
    report |= {"stamps": len(indices), **track.report}
    report |= {"drift": drift, "step_noise": noise}
    print(json.dumps(report, indent=2))
    return 0
