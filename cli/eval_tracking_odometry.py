"""``locnerf eval tracking``'s real odometry and trajectory files: ``--odometry``, ``--passes``, ``--out``.

``--odometry synthetic`` (the default) keeps the simulator's odometry; ``rgbd`` computes OpenCV
RGB-D odometry from the sequence's own frames as they are replayed (``--live``: online, in the ingest, as it releases them);
a file path feeds a recorded TUM or EuRoC trajectory (``--odometry-format``), matched to the
images by stamp and carried to the camera with ``--T-body-cam``. Every report names its
odometry (``odometry``: ``synthetic``, ``rgbd``, ``rgbd-online`` or ``file:<name>``), and with real odometry
its drift against the ground truth (``odometry_drift``, :func:`locnerf.eval.trajectory_output.odometry_drift`).
``--out FOLDER`` writes the JSON report with ``reference.txt``, ``estimate.txt`` and ``odometry.txt``
(TUM) beside it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from locnerf.bags.reader import is_bag
from locnerf.errors import LocnerfInputError
from locnerf.eval.tracking import ConvergenceConfig, TrackingRecord
from locnerf.eval.tracking_plots import plot_error_and_drift
from locnerf.eval.trajectory_output import odometry_drift, write_run_trajectories
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.validation import InvalidPoseError, validate_pose_setting
from locnerf.odometry.sequence import SYNTHETIC, OdometrySourceConfig, RecordedReplay, sequence_track
from locnerf.odometry.tracks import OdometryTrack
from locnerf.sim.paths import CameraPath, SequencePath
from locnerf.sim.scenario import ScenarioConfig, TrackingScenario, run_times

REPORT = "tracking.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--odometry, --odometry-format, --T-body-cam, --passes (:func:`add_source_arguments`), --out."""
    add_source_arguments(parser)
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for tracking.json and the TUM files reference.txt, estimate.txt, odometry.txt (and estimate_after_kidnap.txt)",
    )


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """--odometry, --odometry-format, --T-body-cam, --passes: what :func:`odometry_source` reads (also ``locnerf bag export``'s)."""
    parser.add_argument(
        "--odometry",
        default=SYNTHETIC,
        help="sequence folder: 'synthetic' (from the ground truth with --drift/--noise), 'rgbd' (OpenCV RGB-D odometry of the "
        "sequence's frames; --live: computed online by the ingest as it releases them) or a TUM / EuRoC trajectory FILE matched to the images by stamp",
    )
    parser.add_argument("--odometry-format", default="auto", choices=("auto", "tum", "euroc"), help="--odometry FILE: its format (auto: by its lines)")
    parser.add_argument(
        "--T-body-cam",
        dest="T_body_cam",
        type=Path,
        default=None,
        help="--odometry FILE: text file, the 4x4 camera pose (OpenGL axes) in the file's body frame, m",
    )
    parser.add_argument("--passes", type=int, default=1, help="sequence folder: replay the frames this many times, forward and backward in turn")


def odometry_source(args: argparse.Namespace) -> OdometrySourceConfig:
    """The odometry of --odometry, --odometry-format and --T-body-cam.

    Raises:
        LocnerfInputError / FileNotFoundError: real odometry or --passes on the procedural world,
            a --T-body-cam file that is missing or not a rigid 4x4 transform (the file named).
    """
    if args.passes < 1:
        raise LocnerfInputError(f"--passes {args.passes}: expected at least 1")
    if args.sequence == "world" and (args.odometry != SYNTHETIC or args.passes != 1):
        raise LocnerfInputError("--sequence world: expected --odometry synthetic and --passes 1 (real odometry needs recorded frames)")
    extrinsic = None
    if args.T_body_cam is not None:
        if not args.T_body_cam.is_file():
            raise FileNotFoundError(f"--T-body-cam {args.T_body_cam}: no such file (expected a 4x4 matrix, one row per line)")
        try:
            matrix = np.loadtxt(args.T_body_cam, dtype=np.float64, ndmin=2)
        except ValueError as error:
            raise LocnerfInputError(f"--T-body-cam {args.T_body_cam}: not a table of numbers ({error}); expected a 4x4 matrix") from error
        try:
            extrinsic = validate_pose_setting(matrix.tolist(), f"--T-body-cam {args.T_body_cam}")
        except InvalidPoseError as error:
            raise LocnerfInputError(str(error)) from None
    if args.odometry != SYNTHETIC and args.odometry != "rgbd" and not Path(args.odometry).is_file():
        raise FileNotFoundError(f"--odometry {args.odometry}: no such file (expected 'synthetic', 'rgbd' or a TUM / EuRoC trajectory file)")
    source = args.odometry if args.odometry in (SYNTHETIC, "rgbd") else str(Path(args.odometry).resolve())
    return OdometrySourceConfig(source=source, file_format=args.odometry_format, T_body_cam=extrinsic)


def offline_track(args: argparse.Namespace, path: CameraPath, scenario_config: ScenarioConfig, colour_camera: torch.Tensor | None) -> OdometryTrack | None:
    """The real odometry of the offline run on its stamps; None for the synthetic one."""
    config = odometry_source(args)
    if config.source == SYNTHETIC or not isinstance(path, SequencePath):
        return None
    stamps, path_times = run_times(path, scenario_config)
    return sequence_track(config, RecordedReplay(path, args.sequence, args.split, colour_camera, args.passes), stamps, path_times)


def odometry_label(args: argparse.Namespace, live: bool = False) -> str:
    """What the run's odometry is: ``synthetic``, ``rgbd`` (offline), ``rgbd-online`` (``live``: computed by
    the ingest as it releases the frames) or ``file:<name>`` (a trajectory file, or the bag replayed)."""
    if args.sequence != "world" and is_bag(args.sequence):
        return f"file:{Path(args.sequence).name}"
    return SYNTHETIC if args.sequence == "world" else odometry_source(args).label(live)


def online_odometry_report(ingest: dict[str, int], filter_counters: dict[str, int]) -> dict[str, Any]:
    """``odometry_online``: what the ingest's online odometry did (its last status's ``odometry_*`` counters,
    services/sensor_ingest/odometry_stage.py) in milliseconds and hertz, with the increments the filter
    took as bridging a gap; empty when the ingest computed none."""
    if "odometry_frames" not in ingest:
        return {}
    report: dict[str, Any] = {
        "frames": ingest["odometry_frames"],
        "poses": ingest["odometry_poses"],
        "gaps": ingest["odometry_gaps"],
        "gap_reasons": {k.removeprefix("odometry_gaps_"): v for k, v in ingest.items() if k.startswith("odometry_gaps_")},
        "filter_odometry_gaps": filter_counters.get("odometry_gaps"),
    }
    if "odometry_rate_mhz" in ingest:
        report["rate_hz"] = ingest["odometry_rate_mhz"] / 1000.0
    for name in ("wall", "cpu", "latency"):
        values = {k.rsplit("_", 1)[1]: v / 1000.0 for k, v in ingest.items() if k.startswith(f"odometry_{name}_us_")}
        if values:
            report[f"{name}_ms"] = values
    return {"odometry_online": report}


def scenario_odometry(args: argparse.Namespace, scenario: TrackingScenario, track: OdometryTrack | None) -> dict[str, Any]:
    """The report's ``odometry`` label, and with real odometry its counts and drift."""
    if track is None:
        return {"odometry": odometry_label(args)}
    camera = scenario.odometry @ scenario.path.T_body_cam
    drift = odometry_drift(scenario.stamps, camera, track.valid, scenario.path.poses_at(scenario.path_times))
    return {"odometry": track.label, "odometry_report": track.report, "odometry_drift": drift}


def write_outputs(
    args: argparse.Namespace,
    report: dict[str, Any],
    record: TrackingRecord,
    normalization: MapNormalization,
    criterion: ConvergenceConfig,
    odometry_stamps: torch.Tensor,
    odometry_poses: torch.Tensor,
) -> dict[str, Any]:
    """With --out: the TUM files, ``drift.png`` (the estimate's error beside the odometry's drift, for real
    odometry) and ``tracking.json`` (the report with their paths under ``trajectories``); the report,
    without the drift's series."""
    drift_series = report.get("odometry_drift", {}).get("series")
    if drift_series is not None:
        report = report | {"odometry_drift": {k: v for k, v in report["odometry_drift"].items() if k != "series"}}
    if args.out is None:
        return report
    files = write_run_trajectories(args.out, record, normalization, criterion, odometry_stamps, odometry_poses)
    if drift_series is not None:
        title = f"{Path(args.sequence).name}: estimate and {report['odometry']} odometry"
        files["drift_plot"] = str(plot_error_and_drift(record, drift_series, args.out / "drift.png", title))
    report = report | {"trajectories": files}
    (args.out / REPORT).write_text(json.dumps(report))
    return report
