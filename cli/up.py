"""``locnerf up``: ingest, filter and workers as local processes on the embedded Zenoh default.

This process listens on a loopback endpoint (``--port``, 7447 by default, so that ``locnerf echo
pose`` finds it) and every service connects to it in peer mode; they then find one another by
gossip and talk directly. Ctrl-C stops everything. With ``--duration S`` it stops S seconds after
the first pose and prints a summary (``--json`` for machine-readable output).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from cli.bus_client import DEFAULT_PORT
from cli.monitor import GroundTruthMatcher, PoseError, pose_line
from locnerf.errors import LocnerfInputError
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus, PoseEstimate, PoseStamped
from services.transport import Inbox, TransportConfig, open_bus

STARTUP_TIMEOUT_S = 180.0
STOP_TIMEOUT_S = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf up``."""
    parser.add_argument("--duration", type=float, default=0.0, help="stop this many seconds after the first pose (0: until Ctrl-C)")
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
    parser.set_defaults(func=run, stream_margin=60.0)


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def service_commands(args: argparse.Namespace) -> dict[str, list[str]]:
    """Command lines of every service process, keyed by a log name.

    The ingest streams ``duration · speed + stream_margin`` sensor seconds (``locnerf up`` keeps a
    minute beyond its run; the load test passes the exact length it measures)."""
    base = [sys.executable, "-m", "cli.main", "-v", "run"]
    robot = ["--robot-id", args.robot_id]
    worker = base + ["worker", *robot, "--device", args.device] + (["--config", str(args.worker_config)] if args.worker_config else [])
    commands = {f"worker{i}": worker + ["--worker-id", f"worker{i}"] for i in range(args.workers)}
    commands["filter"] = base + ["filter", *robot, "--device", args.device, "--localizer", args.localizer, "--seed", str(args.seed)] + (
        ["--config", str(args.filter_config)] if args.filter_config else []
    )
    stream_seconds = args.duration * args.speed + args.stream_margin if args.duration > 0 else 24 * 3600.0
    commands["ingest"] = base + [
        "ingest", *robot, "--speed", str(args.speed), "--seed", str(args.seed), "--wait-for-workers", str(args.workers),
        "--duration", str(stream_seconds),
    ] + (["--config", str(args.ingest_config)] if args.ingest_config else [])
    return commands


@dataclass
class RunRecord:
    """What the supervisor saw on the bus."""

    first_pose_at: float | None = None
    poses: int = 0
    errors: list[PoseError] = field(default_factory=list)
    positions: list[tuple[float, float, float]] = field(default_factory=list)
    truth_positions: list[tuple[float, float, float]] = field(default_factory=list)
    status_first: FilterStatus | None = None
    status_last: FilterStatus | None = None
    last_pose: PoseEstimate | None = None


def summary(record: RunRecord, window: float) -> dict[str, object]:
    """The JSON summary of a run."""
    last, first = record.status_last, record.status_first
    counters = last.counters if last else {}
    merged_in_window = counters.get("updates_merged", 0) - (first.counters.get("updates_merged", 0) if first else 0)
    result: dict[str, object] = {
        "duration_s": round(window, 3),
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


def write_config_files(folder: Path, texts: dict[str, str]) -> dict[str, Path]:
    """Write each service's TOML text to ``folder/<name>.toml``; the paths by name."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = {name: folder / f"{name}.toml" for name in texts}
    for name, text in texts.items():
        paths[name].write_text(text)
    return paths


def stop_processes(processes: dict[str, subprocess.Popen]) -> None:
    """SIGINT every child, then wait; SIGKILL the ones still running after the timeout."""
    for process in processes.values():
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for process in processes.values():
        try:
            process.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _observe(record: RunRecord, matcher: GroundTruthMatcher, kind: str, payload: bytes, quiet: bool) -> None:
    if kind == "truth":
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


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise LocnerfInputError(f"--workers {args.workers}: expected at least 1")
    endpoint = f"tcp/127.0.0.1:{args.port or free_port()}"
    bus = open_bus(TransportConfig(listen=(endpoint,)))
    environment = os.environ | {"LOCNERF_ZENOH_MODE": "peer", "LOCNERF_ZENOH_CONNECT": endpoint, "LOCNERF_ZENOH_LISTEN": "tcp/127.0.0.1:0"}
    inbox = Inbox(capacity=4096)
    topics = {"truth": keys.GROUND_TRUTH, "status": keys.STATUS, "pose": keys.POSE}
    handles = [bus.subscribe(keys.key(args.robot_id, t), lambda _k, p, kind=kind: inbox.put((kind, p))) for kind, t in topics.items()]
    args.logs.mkdir(parents=True, exist_ok=True)
    processes: dict[str, subprocess.Popen] = {}
    record, matcher = RunRecord(), GroundTruthMatcher()
    if not args.json:
        print(f"services connect to {endpoint}; logs in {args.logs}; Ctrl-C stops", flush=True)
    started = time.monotonic()
    exit_code = 0
    _interrupt_on_signals()
    try:
        for name, command in service_commands(args).items():
            with open(args.logs / f"{name}.log", "w") as log:
                processes[name] = subprocess.Popen(command, env=environment, stdout=log, stderr=subprocess.STDOUT)
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
                exit_code = 1
                break
            if args.duration > 0 and record.first_pose_at is not None and now - record.first_pose_at >= args.duration:
                break
            failed = [name for name, p in processes.items() if p.poll() not in (None, 0)]
            if failed:
                print(f"service(s) {failed} exited with an error: see {args.logs}", file=sys.stderr)
                exit_code = 1
                break
    except KeyboardInterrupt:
        pass
    finally:
        window = time.monotonic() - record.first_pose_at if record.first_pose_at is not None else 0.0
        stop_processes(processes)
        for handle in handles:
            handle.close()
        bus.close()
    result = summary(record, window)
    if args.plot is not None and record.errors:
        result["plot"] = str(plot_run(record, args.plot))
    print(json.dumps(result, indent=None if args.json else 2), flush=True)
    return exit_code
