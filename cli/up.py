"""``locnerf up``: ingest, filter and workers as local processes on the embedded Zenoh default.

This process listens on a loopback endpoint (``--port``, 7447 by default, so that ``locnerf echo
pose`` finds it) and every service connects to it in peer mode; they then find one another by
gossip and talk directly. Ctrl-C stops everything. With ``--duration S`` it stops S seconds after
the first pose, with ``--until-updates N`` once the filter has merged N updates, and prints a
summary (``--json`` for machine-readable output). The services are ``python -m services.<name>``
processes under a :class:`services.supervisor.Supervisor`, each reading its configuration (the
``--*-config`` file with the flags applied) from ``<logs>/<name>.toml``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from locnerf.errors import LocnerfInputError
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus, Odometry, PoseEstimate, PoseStamped
from locnerf_cli.bus_client import DEFAULT_PORT
from locnerf_cli.monitor import GroundTruthMatcher, PoseError, pose_line
from locnerf_cli.view import check_save_path
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.local_hub import LocalHub
from locnerf_services.nerf_worker.__main__ import WorkerConfig
from locnerf_services.runtime import load_service_config
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.transport import Inbox

STARTUP_TIMEOUT_S = 180.0
VIEW_STARTUP_TIMEOUT_S = 120.0
"""Seconds the view may take to load the map and subscribe before ``locnerf up --view`` gives up."""
STREAM_MARGIN_S = 60.0
"""Sensor seconds the ingest streams beyond ``--duration`` (stretched by ``--speed``)."""
ENDLESS_STREAM_S = 24 * 3600.0
"""Sensor seconds the ingest streams without ``--duration``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf up``."""
    parser.add_argument("--duration", type=float, default=0.0, help="stop this many seconds after the first pose (0: no time limit)")
    parser.add_argument("--until-updates", type=int, default=0, help="stop once the filter has merged this many updates (0: no limit)")
    parser.add_argument("--json", action="store_true", help="print only a JSON summary at the end")
    parser.add_argument("--workers", type=int, default=1, help="NeRF worker processes")
    parser.add_argument("--speed", type=float, default=1.0, help="sensor seconds per wall second of the stream")
    parser.add_argument("--seed", type=int, default=0, help="seed of the stream noise and of the filter")
    parser.add_argument("--robot-id", default="robot", help="robot id")
    parser.add_argument("--localizer", default="llff", help="localizer preset or TOML file")
    parser.add_argument("--device", default="auto", help="device of the filter and workers: auto, cpu, cuda")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="loopback port the services connect to (0: a free one)")
    parser.add_argument("--ingest-config", type=Path, help="TOML for the ingest (IngestConfig)")
    parser.add_argument("--filter-config", type=Path, help="TOML for the filter (FilterProcessConfig)")
    parser.add_argument("--worker-config", type=Path, help="TOML for the workers (WorkerConfig)")
    parser.add_argument("--logs", type=Path, default=Path("out/up/logs"), help="folder for the services' logs")
    parser.add_argument("--plot", type=Path, help="write a PNG of trajectory and error here at the end")
    parser.add_argument("--view", action="store_true", help="start `locnerf view` beside the services (pip install 'locnerf[view]')")
    parser.add_argument("--save", type=Path, help="with --view: the view records to this .rrd file instead of opening the viewer")
    parser.set_defaults(func=run)


@dataclass(frozen=True)
class ServiceConfigs:
    """The configurations of an up-style run: one ingest, one filter, ``workers`` NeRF workers.

    Each is the pydantic model of its process (``IngestConfig``, ``FilterProcessConfig``,
    ``WorkerConfig``); the workers share ``worker`` and get the ids ``worker0``, ``worker1``, ...
    """

    ingest: BaseModel
    filter: BaseModel
    worker: BaseModel
    workers: int


def with_stream_length(ingest: BaseModel, seconds: float) -> BaseModel:
    """``ingest`` (an ``IngestConfig``) with a world stream of ``seconds`` sensor seconds."""
    world = type(ingest.world).model_validate(ingest.world.model_dump() | {"duration": seconds})
    return ingest.model_copy(update={"world": world})


def up_configs(args: argparse.Namespace) -> ServiceConfigs:
    """The configurations of ``locnerf up``: the ``--*-config`` files (or the defaults) with the flags applied.

    The ingest streams ``duration · speed + STREAM_MARGIN_S`` sensor seconds (``ENDLESS_STREAM_S`` without ``--duration``).
    """
    load = load_service_config
    robot_device = {"robot_id": args.robot_id, "device": args.device}
    worker = load(WorkerConfig, args.worker_config, robot_device)
    filter_config = load(FilterProcessConfig, args.filter_config, robot_device | {"localizer": args.localizer, "seed": args.seed})
    ingest = load(IngestConfig, args.ingest_config, {"robot_id": args.robot_id, "speed": args.speed, "seed": args.seed})
    stream_seconds = args.duration * args.speed + STREAM_MARGIN_S if args.duration > 0 else ENDLESS_STREAM_S
    return ServiceConfigs(with_stream_length(ingest, stream_seconds), filter_config, worker, args.workers)


def start_services(supervisor: Any, configs: ServiceConfigs) -> None:
    """Start the workers, the filter and the ingest (which waits until the filter lists every worker)
    under ``supervisor`` (a ``services.supervisor.Supervisor``); their logs are named worker<i>, filter, ingest."""
    for index in range(configs.workers):
        supervisor.start_service(f"worker{index}", "worker", configs.worker.model_copy(update={"worker_id": f"worker{index}"}))
    supervisor.start_service("filter", "filter", configs.filter)
    supervisor.start_service("ingest", "ingest", configs.ingest.model_copy(update={"wait_for_workers": configs.workers}))


@dataclass
class RunRecord:
    """What `locnerf up` saw on the bus."""

    first_pose_at: float | None = None
    poses: int = 0
    pose_stamps: set[float] = field(default_factory=set)
    odometry_stamps: set[float] = field(default_factory=set)
    errors: list[PoseError] = field(default_factory=list)
    positions: list[tuple[float, float, float]] = field(default_factory=list)
    truth_positions: list[tuple[float, float, float]] = field(default_factory=list)
    status_first: FilterStatus | None = None
    status_last: FilterStatus | None = None
    last_pose: PoseEstimate | None = None


def odometry_without_pose(record: RunRecord) -> int:
    """Odometry stamps between the first and the last pose that no pose answered (the filter
    publishes one pose per odometry message)."""
    if not record.pose_stamps:
        return 0
    first, last = min(record.pose_stamps), max(record.pose_stamps)
    return sum(1 for stamp in record.odometry_stamps if first <= stamp <= last and stamp not in record.pose_stamps)


def summary(record: RunRecord, window: float) -> dict[str, object]:
    """The JSON summary of a run."""
    last, first = record.status_last, record.status_first
    counters = last.counters if last else {}
    merged_in_window = counters.get("updates_merged", 0) - (first.counters.get("updates_merged", 0) if first else 0)
    result: dict[str, object] = {
        "duration_s": round(window, 3),
        "poses": record.poses,
        "odometry_without_pose": odometry_without_pose(record),
        "pose_rate_hz": round(record.poses / window, 3) if window > 0 else 0.0,
        "update_hz": round(merged_in_window / window, 3) if window > 0 else 0.0,
        "updates_merged": counters.get("updates_merged", 0),
        "stale_results": counters.get("stale_results", 0),
        "bad_messages": counters.get("bad_messages", 0),
        "update_latency_s": last.update_latency_s if last else None,
        "workers": last.workers if last else [],
        "counters": counters,
    }
    if record.last_pose is not None:
        result |= {"particle_count": record.last_pose.particle_count, "mode": record.last_pose.mode}
    if record.errors:
        result |= {"final_translation_error": round(record.errors[-1].translation, 4), "final_rotation_error_deg": round(record.errors[-1].rotation_deg, 3)}
    return result


def plot_run(record: RunRecord, path: Path) -> Path:
    """Top view of estimated and true trajectory, and the error against time, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_path, ax_error) = plt.subplots(1, 2, figsize=(11, 4.5))
    ax_path.plot([p[0] for p in record.truth_positions], [p[2] for p in record.truth_positions], "k-", label="ground truth")
    ax_path.plot([p[0] for p in record.positions], [p[2] for p in record.positions], "r.", markersize=2, label="estimate")
    ax_path.set_xlabel("x (m)")
    ax_path.set_ylabel("z (m)")
    ax_path.set_aspect("equal")
    ax_path.legend()
    stamps = [e.stamp for e in record.errors]
    ax_error.semilogy(stamps, [max(e.translation, 1e-4) for e in record.errors], label="translation (m)")
    ax_error.semilogy(stamps, [max(e.rotation_deg, 1e-3) for e in record.errors], label="rotation (deg)")
    ax_error.set_xlabel("sensor time (s)")
    ax_error.grid(True, alpha=0.3)
    ax_error.legend()
    figure.suptitle("locnerf services: global localization, then tracking (procedural world)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


def _observe(record: RunRecord, matcher: GroundTruthMatcher, kind: str, payload: bytes, quiet: bool) -> None:
    if kind == "odometry":
        record.odometry_stamps.add(decode(payload, Odometry).stamp)
    elif kind == "truth":
        truth = decode(payload, PoseStamped)
        matcher.add_truth(truth)
        record.truth_positions.append(tuple(row[3] for row in truth.T_world_cam[:3]))
    elif kind == "status":
        record.status_last = decode(payload, FilterStatus)
        if record.first_pose_at is not None and record.status_first is None:
            record.status_first = record.status_last
    else:
        estimate = decode(payload, PoseEstimate)
        if record.first_pose_at is None:
            record.first_pose_at = time.monotonic()
        record.poses += 1
        record.pose_stamps.add(estimate.stamp)
        record.last_pose = estimate
        record.positions.append(tuple(row[3] for row in estimate.T_world_cam[:3]))
        error = matcher.error(estimate)
        if error is not None:
            record.errors.append(error)
        if not quiet and record.poses % 15 == 0:
            print(pose_line(estimate, error), flush=True)


def _interrupt_on_signals() -> None:
    """SIGINT and SIGTERM both stop the run cleanly (also when started in the background, where
    SIGINT is ignored by default)."""

    def handler(signum: int, _frame) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def _finished(record: RunRecord, args: argparse.Namespace, now: float) -> bool:
    """Whether ``--duration`` has passed since the first pose or ``--until-updates`` updates were merged."""
    if record.first_pose_at is None:
        return False
    if args.duration > 0 and now - record.first_pose_at >= args.duration:
        return True
    merged = record.status_last.counters.get("updates_merged", 0) if record.status_last else 0
    return args.until_updates > 0 and merged >= args.until_updates


def start_view(hub: LocalHub, args: argparse.Namespace, map_spec: str) -> bool:
    """``locnerf view`` on the hub as the supervised process ``view`` (log ``view.log``), drawing ``map_spec``;
    waits until it is subscribed and recording (its ``alive/view`` token), so that the recording holds the
    run from its first message. False (and a message on stderr) if the view exited or took longer than
    ``VIEW_STARTUP_TIMEOUT_S``."""
    from locnerf_cli.view import import_rerun

    import_rerun()  # a clear error here rather than a failed process
    command = [sys.executable, "-m", "locnerf_cli.main", "-v", "view", "--connect", hub.endpoint, "--robot-id", args.robot_id, "--map", map_spec]
    ready = threading.Event()
    watch = hub.bus.watch_liveliness(keys.key(args.robot_id, keys.VIEW_ALIVE), lambda _key, alive: alive and ready.set())
    try:
        hub.supervisor.start("view", command + (["--save", str(args.save.resolve())] if args.save is not None else []))
        deadline = time.monotonic() + VIEW_STARTUP_TIMEOUT_S
        while not ready.wait(0.1):
            exited = hub.supervisor.exited().get("view")
            if exited is not None or time.monotonic() > deadline:
                why = f"exited with code {exited}" if exited is not None else f"was not recording within {VIEW_STARTUP_TIMEOUT_S:.0f} s"
                print(f"the view {why}: see {args.logs / 'view.log'}", file=sys.stderr)
                return False
    finally:
        watch.close()
    return True


def _follow(hub: LocalHub, inbox: Inbox, record: RunRecord, matcher: GroundTruthMatcher, args: argparse.Namespace, started: float) -> int:
    """Record what the services publish until the run is finished (0) or a service failed or no pose came (1)."""
    while True:
        item = inbox.get(timeout=0.1)
        if item is not None:
            try:
                _observe(record, matcher, item[0], item[1], args.json)
            except DecodeError as error:
                print(f"bad {item[0]} message: {error}", file=sys.stderr)
        now = time.monotonic()
        if record.first_pose_at is None and now - started > STARTUP_TIMEOUT_S:
            print(f"no pose within {STARTUP_TIMEOUT_S} s: see the logs in {args.logs}", file=sys.stderr)
            return 1
        if _finished(record, args, now):
            return 0
        failed = {name: code for name, code in hub.supervisor.exited().items() if code != 0}
        if failed:
            print(f"service(s) exited with an error {failed}: see {args.logs}", file=sys.stderr)
            return 1


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise LocnerfInputError(f"--workers {args.workers}: expected at least 1")
    if args.until_updates < 0:
        raise LocnerfInputError(f"--until-updates {args.until_updates}: expected 0 (no limit) or more")
    if args.save is not None and not args.view:
        raise LocnerfInputError(f"--save {args.save}: expected --view too (the view writes the recording)")
    check_save_path(args.save)
    configs = up_configs(args)
    hub = LocalHub(args.logs, port=args.port)
    inbox = Inbox(capacity=4096)
    topics = {"odometry": keys.ODOMETRY, "truth": keys.GROUND_TRUTH, "status": keys.STATUS, "pose": keys.POSE}
    for kind, topic in topics.items():
        hub.subscribe(keys.key(args.robot_id, topic), lambda _k, p, kind=kind: inbox.put((kind, p)))
    record, matcher = RunRecord(), GroundTruthMatcher()
    if not args.json:
        print(f"services connect to {hub.endpoint}; logs in {args.logs}; Ctrl-C stops", flush=True)
    exit_code = 0
    _interrupt_on_signals()
    try:
        if args.view and not start_view(hub, args, configs.worker.map):
            exit_code = 1
        else:
            start_services(hub.supervisor, configs)
            exit_code = _follow(hub, inbox, record, matcher, args, started=time.monotonic())
    except KeyboardInterrupt:
        pass
    finally:
        window = time.monotonic() - record.first_pose_at if record.first_pose_at is not None else 0.0
        hub.close()
    result = summary(record, window)
    if args.plot is not None and record.errors:
        result["plot"] = str(plot_run(record, args.plot))
    print(json.dumps(result, indent=None if args.json else 2), flush=True)
    return exit_code
