"""``locnerf eval tracking --live``: the tracking experiment through the real services at real speed.

Ingest, filter and K workers start as separate processes on loopback Zenoh (peer mode, multicast
scouting off, explicit ``tcp/127.0.0.1`` endpoints on free ports), as ``locnerf up`` and
``locnerf loadtest`` start them. The ingest serves the offline run's scenario (source
``scenario``: same path, odometry noise model and parameters, images, kidnapping and seed), or the
bag given as ``--sequence`` (source ``rosbag``), paced at one sensor second per wall second; the filter starts globally (uniform over the map's camera
bounds, yaw unknown: its ``start = "global"``) with the localizer ``--config``/``--preset``; this
process records odometry, ground truth, poses and update results and scores them with
:mod:`locnerf.eval.tracking_live`.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

import torch

from locnerf.bags.reader import bag_extent, is_bag
from locnerf.data.colour_camera import check_map_poses, map_colour_camera
from locnerf.data.map_lens import MapLens, map_lens
from locnerf.errors import LocnerfInputError
from locnerf.eval.tracking import BACK_ON_TRACK, ConvergenceConfig
from locnerf.eval.tracking_live import LiveObservations, live_record, live_summary
from locnerf.eval.trajectory_output import odometry_drift
from locnerf.field.protocol import MapNormalization
from locnerf.maps.source import WORLD, open_map
from locnerf.messages import keys
from locnerf.messages.codec import decode
from locnerf.messages.schemas import FilterStatus, Odometry, PoseEstimate, PoseStamped, ServiceStatus, UpdateResult
from locnerf_cli import eval_tracking_odometry
from locnerf_cli.up import ServiceConfigs, start_services
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.local_hub import LocalHub
from locnerf_services.nerf_worker.__main__ import WorkerConfig
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.sensor_ingest.odometry_stage import OnlineOdometryConfig
from locnerf_services.transport import Inbox

logger = logging.getLogger(__name__)

ROBOT_ID = "evaltrack"
STARTUP_TIMEOUT_S = 240.0
SETTLE_S = 3.0  # wall seconds after the ingest's last message, at most, for the last poses and results
QUIET_S = 0.75  # the filter has finished once no pose or update result came for this long (and a status after them)


def scenario_settings(
    args: argparse.Namespace, image_rate: float, vio: dict[str, float], colour_camera: torch.Tensor | None = None, lens: MapLens | None = None
) -> dict[str, Any]:
    """The ingest's ``scenario`` fields (``ScenarioSourceConfig``) for the command's arguments and the map's colour camera and lens."""
    return {
        "sequence": args.sequence if args.sequence == WORLD else str(Path(args.sequence).resolve()),
        "split": args.split,
        "downscale": args.downscale,
        "speed": args.speed,
        "frame_rate": args.frame_rate,
        "duration": args.duration,
        "image_rate": image_rate,
        "kidnap_at": args.kidnap_at,
        "kidnap_shift": getattr(args, "kidnap_shift", None),
        "vio": vio,
        "T_depth_colour": None if colour_camera is None else colour_camera.tolist(),
        "lens": None if lens is None else lens.model_dump(),
        "passes": args.passes,
        "poses": args.poses,
        "odometry": eval_tracking_odometry.odometry_source(args).model_dump(),
    }


def service_configs(
    args: argparse.Namespace,
    image_rate: float,
    vio: dict[str, float],
    events: int,
    colour_camera: torch.Tensor | None = None,
    lens: MapLens | None = None,
) -> ServiceConfigs:
    """The ingest, filter and worker configurations of the live run.

    The ingest produces its whole stream (``events`` events) before the clock starts, as the load
    test does, so reading or rendering frames does not load the machine under test; with
    ``--odometry rgbd`` that stream carries the RGB-D frames, and the ingest computes the odometry
    online as it releases them (its cost loads the measured run).
    """
    map_spec = args.map if args.map == WORLD else str(Path(args.map).resolve())
    localizer = str(Path(args.config).resolve()) if args.config is not None else args.preset
    common = {"robot_id": ROBOT_ID, "seed": args.seed}
    if args.sequence != WORLD and is_bag(args.sequence):
        source = {"source": "rosbag", "rosbag": {"path": str(Path(args.sequence).resolve())}}
    else:
        scenario = scenario_settings(args, image_rate, vio, colour_camera, lens)
        source = {"source": "scenario", "scenario": scenario, "odometry": OnlineOdometryConfig(rgbd=scenario["odometry"]["rgbd"])}
    ingest = IngestConfig(prefetch_events=events, prefill=True, speed=1.0, **source, **common)
    loop = FilterLoopConfig(updates_per_image=args.updates_per_image, odometry_rate=args.odom_rate)
    filter_config = FilterProcessConfig(map=map_spec, device=args.device, localizer=localizer, loop=loop, **common)
    worker = WorkerConfig(map=map_spec, device=args.device, robot_id=ROBOT_ID)
    return ServiceConfigs(ingest, filter_config, worker, args.workers)


def _observe(observed: LiveObservations, kind: str, payload: bytes, arrival: float) -> None:
    if kind == "odometry":
        odometry = decode(payload, Odometry)
        observed.odometry.append((odometry.stamp, arrival))
        observed.odometry_poses[odometry.stamp] = torch.tensor(odometry.T_odom_body, dtype=torch.float64)
    elif kind == "truth":
        truth = decode(payload, PoseStamped)
        observed.truth[truth.stamp] = torch.tensor(truth.T_world_cam, dtype=torch.float64)
    elif kind == "pose":
        pose = decode(payload, PoseEstimate)
        observed.poses.append((pose.stamp, arrival, torch.tensor(pose.T_world_cam, dtype=torch.float64)))
        observed.particle_counts.append(pose.particle_count)
    elif kind == "status":
        observed.filter_counters = decode(payload, FilterStatus).counters
    elif kind == "ingest":
        observed.ingest_counters = decode(payload, ServiceStatus).counters
    else:
        observed.updates[decode(payload, UpdateResult).request_id] = arrival


def settle(last_arrival: dict[str, float]) -> None:
    """Wait, after the ingest has exited, until the filter has finished: no pose or update result for
    ``QUIET_S`` and a filter status published after the last of them (so its counters include every
    update), at most ``SETTLE_S``. ``last_arrival``: monotonic arrival time of the newest message per kind."""
    give_up = time.monotonic() + SETTLE_S
    while time.monotonic() < give_up:
        last_output = max(last_arrival["pose"], last_arrival["result"])
        if time.monotonic() - last_output >= QUIET_S and last_arrival["status"] > last_output:
            return
        time.sleep(0.05)


def record_run(configs: ServiceConfigs, folder: Path, sensor_seconds: float) -> LiveObservations:
    """Start the services, record the bus until the ingest has streamed everything, stop them.

    Raises:
        RuntimeError: a service failed, or the run took longer than ``STARTUP_TIMEOUT_S`` plus
            four times ``sensor_seconds``.
    """
    hub = LocalHub(folder)
    inbox = Inbox(capacity=1 << 17)
    topics = {
        "odometry": keys.key(ROBOT_ID, keys.ODOMETRY),
        "truth": keys.key(ROBOT_ID, keys.GROUND_TRUTH),
        "pose": keys.key(ROBOT_ID, keys.POSE),
        "result": keys.key(ROBOT_ID, keys.UPDATE_RESULT),
        "status": keys.key(ROBOT_ID, keys.STATUS),
        "ingest": keys.key(ROBOT_ID, keys.INGEST_STATUS, ingest_id="*"),
    }
    # Callbacks only stamp and enqueue; decoding happens after the run, off the measured CPU.
    last_arrival = dict.fromkeys(topics, 0.0)

    def arrived(kind: str) -> float:
        last_arrival[kind] = time.monotonic()
        return last_arrival[kind]

    for kind, topic in topics.items():
        hub.subscribe(topic, lambda _k, p, kind=kind: inbox.put((kind, p, arrived(kind))))
    observed = LiveObservations()
    try:
        start_services(hub.supervisor, configs)
        give_up = time.monotonic() + STARTUP_TIMEOUT_S + sensor_seconds * 4
        while True:
            hub.supervisor.check_running(allowed_to_exit=("ingest",))
            if "ingest" in hub.supervisor.exited():
                break
            if time.monotonic() > give_up:
                raise RuntimeError(f"the run took more than {STARTUP_TIMEOUT_S + sensor_seconds * 4:.0f} s: see the logs in {folder}")
            time.sleep(0.2)
        settle(last_arrival)
    finally:
        hub.close()
    while (item := inbox.get(timeout=0.0)) is not None:
        _observe(observed, *item)
    if inbox.dropped:
        logger.warning("the observer dropped %d messages (inbox full)", inbox.dropped)
    return observed


def run_live(
    args: argparse.Namespace,
    criterion: ConvergenceConfig,
    image_rate: float,
    vio: dict[str, float],
    sensor_seconds: float,
    back_on_track: ConvergenceConfig = BACK_ON_TRACK,
) -> dict[str, Any]:
    """Run the live experiment; the report (see :func:`locnerf.eval.tracking_live.live_summary`),
    with the error series of the scored poses under ``series`` when ``--json`` asks for it, as offline.

    ``sensor_seconds`` is the scenario's length (for the prefetch size and the timeout).
    """
    if args.workers < 1:
        raise LocnerfInputError(f"--workers {args.workers}: expected at least 1")
    radiance_map = open_map(args.map, torch.device("cpu"))
    check_map_poses(radiance_map, args.poses)
    colour_camera = map_colour_camera(radiance_map)
    if args.sequence != WORLD and is_bag(args.sequence):
        events = bag_extent(args.sequence)[1] + 16  # at most one event per message
    else:
        events = int(sensor_seconds * (2 * vio["rate"] + image_rate)) + 16
    observed = record_run(service_configs(args, image_rate, vio, events, colour_camera, map_lens(radiance_map)), args.logs, sensor_seconds)
    report = live_summary(observed, radiance_map.normalization, args.kidnap_at, criterion, series=args.json, back_on_track=back_on_track)
    report |= {"live": True, "workers": args.workers, "image_rate": image_rate, "logs": str(args.logs)}
    return live_odometry_outputs(args, observed, report, radiance_map.normalization, criterion)


def live_odometry_outputs(
    args: argparse.Namespace, observed: LiveObservations, report: dict[str, Any], normalization: MapNormalization, criterion: ConvergenceConfig
) -> dict[str, Any]:
    """The report with the odometry's label (and its drift against the ground truth seen on the bus,
    for real odometry), and with ``--out`` the TUM files and ``tracking.json`` written."""
    stamps = sorted(observed.odometry_poses)
    poses = torch.stack([observed.odometry_poses[s] for s in stamps]) if stamps else torch.zeros(0, 4, 4, dtype=torch.float64)
    label = eval_tracking_odometry.odometry_label(args, live=True)
    report = report | {"odometry": label} | eval_tracking_odometry.online_odometry_report(observed.ingest_counters, observed.filter_counters)
    truth_stamps = [s for s in stamps if s in observed.truth]
    if label != "synthetic" and len(truth_stamps) >= 2:
        index = torch.tensor([stamps.index(s) for s in truth_stamps])
        truth = torch.stack([observed.truth[s] for s in truth_stamps])
        report["odometry_drift"] = odometry_drift(
            torch.tensor(truth_stamps, dtype=torch.float64), poses[index], torch.ones(len(index), dtype=torch.bool), truth
        )
    record = live_record(observed, normalization, args.kidnap_at)
    return eval_tracking_odometry.write_outputs(args, report, record, normalization, criterion, torch.tensor(stamps, dtype=torch.float64), poses)
