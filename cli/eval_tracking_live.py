"""``locnerf eval tracking --live``: the tracking experiment through the real services at real speed.

Ingest, filter and K workers start as separate processes on loopback Zenoh (peer mode, multicast
scouting off, explicit ``tcp/127.0.0.1`` endpoints on free ports), as ``locnerf up`` and
``locnerf loadtest`` start them. The ingest serves the offline run's scenario (source
``scenario``: same path, odometry noise model and parameters, images, kidnapping and seed), paced
at one sensor second per wall second; the filter starts globally (uniform over the map's camera
bounds, yaw unknown: its ``start = "global"``) with the localizer ``--config``/``--preset``; this
process records odometry, ground truth, poses and update results and scores them with
:mod:`locnerf.eval.tracking_live`.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import time
from pathlib import Path
from typing import Any

import torch

from cli.up import free_port, service_commands, stop_processes, write_config_files
from locnerf.errors import LocnerfInputError
from locnerf.eval.tracking import ConvergenceConfig
from locnerf.eval.tracking_live import LiveObservations, live_summary
from locnerf.maps.source import WORLD, open_map
from locnerf.messages import keys
from locnerf.messages.codec import decode
from locnerf.messages.schemas import Odometry, PoseEstimate, PoseStamped, UpdateResult
from services.transport import Inbox, TransportConfig, open_bus

logger = logging.getLogger(__name__)

ROBOT_ID = "evaltrack"
STARTUP_TIMEOUT_S = 240.0
SETTLE_S = 3.0  # wall seconds after the ingest's last message for the last poses and results


def _toml_value(value: Any) -> str:
    """A TOML literal of a JSON-like scalar or list (strings, numbers, booleans)."""
    return json.dumps(value)


def _toml(tables: dict[str, dict[str, Any]]) -> str:
    """A TOML document: table "" holds the top-level keys; None values are left out (the default)."""
    lines = []
    for name, entries in tables.items():
        if name:
            lines.append(f"\n[{name}]")
        lines += [f"{key} = {_toml_value(value)}" for key, value in entries.items() if value is not None]
    return "\n".join(lines) + "\n"


def scenario_table(args: argparse.Namespace, image_rate: float, vio: dict[str, float]) -> dict[str, dict[str, Any]]:
    """The ingest's ``[scenario]`` and ``[scenario.vio]`` tables for the command's arguments."""
    scenario = {
        "sequence": args.sequence if args.sequence == WORLD else str(Path(args.sequence).resolve()),
        "split": args.split,
        "downscale": args.downscale,
        "speed": args.speed,
        "duration": args.duration,
        "image_rate": image_rate,
        "kidnap_at": args.kidnap_at,
    }
    return {"scenario": scenario, "scenario.vio": vio}


def write_configs(args: argparse.Namespace, folder: Path, image_rate: float, vio: dict[str, float], events: int) -> argparse.Namespace:
    """Write the ingest, filter and worker TOMLs into ``folder``; the namespace ``service_commands`` expects.

    The ingest produces its whole stream (``events`` events) before the clock starts, as the load
    test does, so reading or rendering frames does not load the machine under test.
    """
    map_spec = args.map if args.map == WORLD else str(Path(args.map).resolve())
    localizer = str(Path(args.config).resolve()) if args.config is not None else args.preset
    files = {
        "ingest": _toml({"": {"source": "scenario", "prefetch_events": events, "prefill": True}} | scenario_table(args, image_rate, vio)),
        "filter": _toml({"": {"map": map_spec}}),
        "worker": _toml({"": {"map": map_spec}}),
    }
    paths = write_config_files(folder, files)
    return argparse.Namespace(
        robot_id=ROBOT_ID, device=args.device, workers=args.workers, localizer=localizer, seed=args.seed,
        filter_config=paths["filter"], worker_config=paths["worker"], ingest_config=paths["ingest"], duration=0.0, speed=1.0, stream_margin=0.0,
    )


def _observe(observed: LiveObservations, kind: str, payload: bytes, arrival: float) -> None:
    if kind == "odometry":
        observed.odometry.append((decode(payload, Odometry).stamp, arrival))
    elif kind == "truth":
        truth = decode(payload, PoseStamped)
        observed.truth[truth.stamp] = torch.tensor(truth.T_world_cam, dtype=torch.float64)
    elif kind == "pose":
        pose = decode(payload, PoseEstimate)
        observed.poses.append((pose.stamp, arrival, torch.tensor(pose.T_world_cam, dtype=torch.float64)))
        observed.particle_counts.append(pose.particle_count)
    else:
        observed.updates[decode(payload, UpdateResult).request_id] = arrival


def record_run(args: argparse.Namespace, namespace: argparse.Namespace, folder: Path, sensor_seconds: float) -> LiveObservations:
    """Start the services, record the bus until the ingest has streamed everything, stop them.

    Raises:
        RuntimeError: a service failed, or no pose within ``STARTUP_TIMEOUT_S``.
    """
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_bus(TransportConfig(listen=(endpoint,)))
    environment = os.environ | {"LOCNERF_ZENOH_MODE": "peer", "LOCNERF_ZENOH_CONNECT": endpoint, "LOCNERF_ZENOH_LISTEN": "tcp/127.0.0.1:0"}
    inbox = Inbox(capacity=1 << 17)
    topics = {
        "odometry": keys.key(ROBOT_ID, keys.ODOMETRY),
        "truth": keys.key(ROBOT_ID, keys.GROUND_TRUTH),
        "pose": keys.key(ROBOT_ID, keys.POSE),
        "result": keys.key(ROBOT_ID, keys.UPDATE_RESULT),
    }
    # Callbacks only stamp and enqueue; decoding happens after the run, off the measured CPU.
    handles = [bus.subscribe(t, lambda _k, p, kind=kind: inbox.put((kind, p, time.monotonic()))) for kind, t in topics.items()]
    processes: dict[str, subprocess.Popen] = {}
    observed = LiveObservations()
    try:
        for name, command in service_commands(namespace).items():
            with open(folder / f"{name}.log", "w") as log:
                processes[name] = subprocess.Popen(command, env=environment, stdout=log, stderr=subprocess.STDOUT)
        give_up = time.monotonic() + STARTUP_TIMEOUT_S + sensor_seconds * 4
        while processes["ingest"].poll() is None:
            failed = [name for name, p in processes.items() if p.poll() is not None and name != "ingest"]
            if failed or time.monotonic() > give_up:
                raise RuntimeError(f"service(s) {failed} exited early or the run timed out: see the logs in {folder}")
            time.sleep(0.2)
        if processes["ingest"].returncode != 0:
            raise RuntimeError(f"the ingest exited with {processes['ingest'].returncode}: see {folder / 'ingest.log'}")
        time.sleep(SETTLE_S)
    finally:
        stop_processes(processes)
        for handle in handles:
            handle.close()
        bus.close()
    while (item := inbox.get(timeout=0.0)) is not None:
        _observe(observed, *item)
    if inbox.dropped:
        logger.warning("the observer dropped %d messages (inbox full)", inbox.dropped)
    return observed


def run_live(args: argparse.Namespace, criterion: ConvergenceConfig, image_rate: float, vio: dict[str, float], sensor_seconds: float) -> dict[str, Any]:
    """Run the live experiment; the report (see :func:`locnerf.eval.tracking_live.live_summary`).

    ``sensor_seconds`` is the scenario's length (for the prefetch size and the timeout).
    """
    if args.workers < 1:
        raise LocnerfInputError(f"--workers {args.workers}: expected at least 1")
    normalization = open_map(args.map, torch.device("cpu")).normalization
    events = int(sensor_seconds * (2 * vio["rate"] + image_rate)) + 16
    namespace = write_configs(args, args.logs, image_rate, vio, events)
    observed = record_run(args, namespace, args.logs, sensor_seconds)
    report = live_summary(observed, normalization, args.kidnap_at, criterion)
    return report | {"live": True, "workers": args.workers, "image_rate": image_rate, "logs": str(args.logs)}
