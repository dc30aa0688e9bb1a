"""``locnerf loadtest``: drive the services with a synthetic stream and measure them.

Starts ingest, filter and K workers as local processes (as ``locnerf up`` does) on the procedural
world (``--map world``) or a map file (``--map FILE``: filter and workers use the map, the stream
is still the procedural world, so accuracy means nothing there, only load), waits for the first
pose and ``--warmup`` seconds, then observes the bus for ``--duration`` seconds and reports rates,
latencies, jitter, dropped frames vs lost messages and CPU/memory per process (JSON with
``--json``, else a table). Comma-separated ``--particles``, ``--pixels`` or ``--workers`` make a
sweep: one run per combination, a CSV and a PNG in ``--out``. ``--overload F`` sends odometry and
images F times faster than their rates (the held-load test of docs/RELIABILITY.md).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import time
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, model_validator

from locnerf.config import preset
from locnerf.eval.loadtest_process import ProcessSample, process_usage, read_process_sample
from locnerf.eval.loadtest_recorder import LoadRecorder
from locnerf.eval.loadtest_sweep import plot_sweep, write_sweep_csv
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError
from locnerf_cli.flags import from_flags
from locnerf_cli.up import ServiceConfigs, start_services
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.local_hub import LocalHub
from locnerf_services.nerf_worker.__main__ import WorkerConfig
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.supervisor import write_config
from locnerf_services.transport import Inbox

FIRST_POSE_TIMEOUT_S = 180.0


class LoadCaseConfig(BaseModel):
    """One load-test run: the load, the stream and how long to measure."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    particles: int = Field(300, ge=1, description="Particles of the filter (held: no reduction when annealing).")
    pixels: int = Field(64, ge=1, description="Pixels per particle in each update (M).")
    workers: int = Field(1, ge=1, description="NeRF worker processes sharing each update.")
    camera_rate: float = Field(15.0, gt=0, description="Camera frames per second of the synthetic stream.")
    odometry_rate: float = Field(15.0, gt=0, description="Odometry messages per second (the pose rate).")
    duration: float = Field(20.0, gt=0, description="Measurement window, seconds.")
    warmup: float = Field(3.0, ge=0, description="Seconds after the first pose that are not measured.")
    settle: float = Field(
        5.0,
        ge=0,
        description="Seconds after the window during which answers to its messages still count (the filter's update_timeout); the run goes on once all are in.",
    )
    map: str = Field("world", description="'world' (the procedural world) or a map file for the filter and workers.")
    device: str = Field("auto", description="Device of the filter and workers: auto, cpu, cuda.")
    seed: int = Field(0, description="Seed of the stream and the filter.")
    robot_id: str = Field("loadtest", description="Robot id of the keys.")
    prerender: bool = Field(
        True,
        description="The ingest renders the whole synthetic stream before releasing it (IngestConfig.prefill), so "
        "the frame rendering of the test's camera does not load the machine under test; false renders while streaming.",
    )
    overload: float = Field(
        1.0,
        ge=1.0,
        description="Input faster than processing: odometry and camera rates are multiplied by this. Above 1 the ingest "
        "renders only OVERLOAD_FRAMES frames and sends them again in turn (no prerendering), and the observer leaves the "
        "images alone (the filter's status counts them) and decodes the rest during the window, so that a long run "
        "holds no queue of its own.",
    )
    memory_period: float = Field(5.0, gt=0, description="Seconds between two readings of every process's resident memory.")

    @model_validator(mode="after")
    def _images_on_the_odometry_grid(self) -> LoadCaseConfig:
        """The simulated camera takes its images at odometry stamps (locnerf.sim.scenario)."""
        if self.camera_rate > self.odometry_rate:
            raise ValueError(f"camera_rate {self.camera_rate} Hz above odometry_rate {self.odometry_rate} Hz: expected camera_rate <= odometry_rate")
        return self

    @property
    def input_odometry_rate(self) -> float:
        """Odometry messages per second actually sent."""
        return self.odometry_rate * self.overload

    @property
    def input_camera_rate(self) -> float:
        """Camera frames per second actually sent."""
        return self.camera_rate * self.overload

    @property
    def overloaded(self) -> bool:
        """Whether this is a held-load run."""
        return self.overload > 1.0


OVERLOAD_FRAMES = 30
"""Distinct frames of an overloaded stream (two seconds of the default camera)."""


# Seconds of stream after the measurement window's settle time: the ingest starts streaming once
# the workers are up (--wait-for-workers), so the first pose follows within a frame.
_STREAM_MARGIN_S = 5.0


def service_configs(case: LoadCaseConfig, folder: Path) -> ServiceConfigs:
    """The ingest, filter and worker configurations of ``case``; its localizer is written to ``folder/localizer.toml``.

    The ingest streams the world for warm-up, window, settle time and a margin, at the case's input
    rates; a held-load case reuses ``OVERLOAD_FRAMES`` frames, any other renders its whole stream
    before the first release unless ``case.prerender`` is off.
    """
    stream_seconds = case.warmup + case.duration + case.settle + _STREAM_MARGIN_S
    # World stream events: a ground truth and an odometry message per odometry stamp, an image per frame.
    events = math.ceil(stream_seconds * (2 * case.input_odometry_rate + case.input_camera_rate)) + 8
    localizer = preset("llff", particles=case.particles, measurement={"pixels": case.pixels}, annealing={"reduced_particles": case.particles})
    localizer_file = write_config(folder / "localizer.toml", localizer)
    world = {"vio": {"rate": case.input_odometry_rate}, "image_rate": case.input_camera_rate, "duration": stream_seconds}
    if case.overloaded:
        world["distinct_frames"] = OVERLOAD_FRAMES
    prefill = case.prerender and not case.overloaded
    common = {"robot_id": case.robot_id, "seed": case.seed}
    ingest = IngestConfig(source="world", world=world, speed=1.0, **({"prefetch_events": events, "prefill": True} if prefill else {}), **common)
    filter_config = FilterProcessConfig(map=case.map, device=case.device, localizer=str(localizer_file), **common)
    worker = WorkerConfig(map=case.map, device=case.device, robot_id=case.robot_id)
    return ServiceConfigs(ingest, filter_config, worker, case.workers)


def _sample_all(processes: dict[str, int]) -> dict[str, ProcessSample]:
    return {name: read_process_sample(pid) for name, pid in processes.items()}


def memory_over_time(samples: list[dict[str, ProcessSample]]) -> dict[str, dict[str, float]]:
    """Per process: resident memory at the first and last reading, its maximum over all readings, MB."""
    return {
        name: {
            "rss_start_mb": round(samples[0][name].rss_mb, 1),
            "rss_max_mb": round(max(sample[name].rss_mb for sample in samples), 1),
            "rss_end_mb": round(samples[-1][name].rss_mb, 1),
        }
        for name in samples[0]
    }


def run_case(case: LoadCaseConfig, folder: Path) -> dict[str, object]:
    """Run one load test; the report (see ``locnerf.eval.loadtest_recorder``) plus per-process CPU
    and memory. Logs and configs go to ``folder``.

    Raises:
        RuntimeError: no pose within ``FIRST_POSE_TIMEOUT_S`` or a service exited early.
    """
    configs = service_configs(case, folder)
    hub = LocalHub(folder)
    inbox = Inbox(capacity=65536)
    topics = {
        "odometry": keys.key(case.robot_id, keys.ODOMETRY),
        "image": keys.key(case.robot_id, keys.IMAGE),
        "request": keys.key(case.robot_id, keys.UPDATE_REQUEST, worker_id="*"),
        "result": keys.key(case.robot_id, keys.UPDATE_RESULT),
        "pose": keys.key(case.robot_id, keys.POSE),
        "status": keys.key(case.robot_id, keys.STATUS),
    }
    if case.overloaded:
        del topics["image"]
    for kind, topic in topics.items():
        hub.subscribe(topic, lambda _k, p, kind=kind: inbox.put((kind, p, time.monotonic())))
    recorder = LoadRecorder(odometry_rate=case.input_odometry_rate, camera_rate=case.input_camera_rate)

    def observe(item: tuple[str, bytes, float]) -> None:
        try:
            recorder.observe(*item)
        except DecodeError as error:
            raise RuntimeError(f"bad {item[0]} message on the bus: {error}") from error

    def drain_until(deadline: float) -> None:
        while time.monotonic() < deadline:
            item = inbox.get(timeout=0.05)
            if item is not None:
                observe(item)
            hub.supervisor.check_running()

    memory: list[dict[str, ProcessSample]] = []

    def wait_until(deadline: float) -> None:
        # Arrivals are stamped in the callbacks and stay queued: decoding them now would take CPU
        # and the GIL from the callbacks and the services while they are being measured. A held-load
        # run decodes as it goes instead (its queue would grow for the whole run).
        while time.monotonic() < deadline:
            if case.overloaded:
                drain_until(min(deadline, time.monotonic() + 0.1))
            else:
                time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
            hub.supervisor.check_running()
            if memory and time.monotonic() - next(iter(memory[-1].values())).at >= case.memory_period:
                memory.append(_sample_all(pids))

    def settle(start: float, end: float, deadline: float) -> None:
        # After the window the arrivals are decoded as they come, and the wait ends as soon as every
        # message of the window has its answer (a late answer still counts until the deadline).
        while True:
            while (item := inbox.get(timeout=0.0)) is not None:
                observe(item)
            if recorder.unanswered(start, end) == 0 or time.monotonic() >= deadline:
                return
            drain_until(min(deadline, time.monotonic() + 0.1))

    try:
        start_services(hub.supervisor, configs)
        give_up = time.monotonic() + FIRST_POSE_TIMEOUT_S
        while not recorder.poses:
            if time.monotonic() > give_up:
                raise RuntimeError(f"no pose within {FIRST_POSE_TIMEOUT_S} s: see the logs in {folder}")
            drain_until(time.monotonic() + 0.2)
        wait_until(time.monotonic() + case.warmup)
        pids = {name: p.pid for name, p in hub.supervisor.processes.items()} | {"loadtest": os.getpid()}
        start, before = time.monotonic(), _sample_all(pids)
        memory.append(before)
        wait_until(start + case.duration)
        end, after = time.monotonic(), _sample_all(pids)
        memory.append(after)
        window_memory = list(memory)
        settle(start, end, end + case.settle)
    finally:
        hub.close()
    while (item := inbox.get(timeout=0.0)) is not None:
        observe(item)
    report = recorder.report(start, end, observer_drops=inbox.dropped)
    case_fields = case.model_dump(include={"particles", "pixels", "workers", "camera_rate", "odometry_rate", "overload", "map", "device"})
    usage = memory_over_time(window_memory)
    return (
        case_fields
        | {"rays": case.particles * case.pixels}
        | report
        | {"processes": {name: process_usage(before[name], after[name]) | usage[name] for name in pids}}
    )


TABLE_ROWS = (
    ("update rate", "update_hz", "Hz"),
    ("update latency p50", "update_latency_p50_ms", "ms"),
    ("update latency p95", "update_latency_p95_ms", "ms"),
    ("update latency p99", "update_latency_p99_ms", "ms"),
    ("worker compute p50", "worker_compute_p50_ms", "ms"),
    ("pose rate", "pose_rate_hz", "Hz"),
    ("pose jitter p50", "pose_jitter_p50_ms", "ms"),
    ("pose jitter p99", "pose_jitter_p99_ms", "ms"),
    ("odometry jitter p99 (source)", "odometry_jitter_p99_ms", "ms"),
    ("odometry -> pose p50", "end_to_end_latency_p50_ms", "ms"),
    ("odometry -> pose p99", "end_to_end_latency_p99_ms", "ms"),
    ("camera frames", "camera_frames", ""),
    ("dropped frames (newest-only)", "dropped_frames", ""),
    ("images replaced (filter status)", "images_replaced", ""),
    ("odometry messages", "odometry_messages", ""),
    ("lost messages", "lost_messages", ""),
)


def format_table(report: dict[str, object]) -> str:
    """The readable form of one report."""
    title = f"{report['particles']} particles x {report['pixels']} pixels, {report['workers']} worker(s), map {report['map']}, {report['window_s']} s"
    lines = [title] + [f"  {label:<30} {report[key]!s:>10} {unit}" for label, key, unit in TABLE_ROWS]
    lines.append(f"  {'process':<12} {'cpu %':>7} {'rss start':>9} {'rss max':>8} {'rss end':>8} {'peak MB':>8} {'threads':>7}")
    for name, u in report["processes"].items():
        lines.append(
            f"  {name:<12} {u['cpu_percent']:>7} {u['rss_start_mb']:>9} {u['rss_max_mb']:>8} {u['rss_end_mb']:>8} {u['peak_rss_mb']:>8} {u['threads']:>7}"
        )
    return "\n".join(lines)


def _int_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated integers, e.g. 100,300") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected positive integers")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf loadtest``."""
    parser.add_argument("--particles", type=_int_list, default=[300], help="particle count(s), comma-separated for a sweep")
    parser.add_argument("--pixels", type=_int_list, default=[64], help="pixels per particle, comma-separated for a sweep")
    parser.add_argument("--workers", type=_int_list, default=[1], help="worker count(s), comma-separated for a sweep")
    parser.add_argument("--camera-rate", type=float, default=15.0, help="camera frames per second")
    parser.add_argument("--odometry-rate", type=float, default=15.0, help="odometry messages per second")
    parser.add_argument("--duration", type=float, default=20.0, help="measured seconds per case")
    parser.add_argument("--warmup", type=float, default=3.0, help="seconds after the first pose not measured")
    parser.add_argument("--map", default="world", help="'world' or a map file for the filter and workers")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--render-live", action="store_true", help="render the synthetic stream while streaming (default: before, see prerender)")
    parser.add_argument("--overload", type=float, default=1.0, help="send odometry and images this many times faster (held load, e.g. 10)")
    parser.add_argument("--memory-period", type=float, default=5.0, help="seconds between two readings of every process's memory")
    parser.add_argument("--out", type=Path, default=Path("out/loadtest"), help="folder for logs, configs and the sweep's CSV/PNG")
    parser.add_argument("--json", action="store_true", help="print JSON only (a list for a sweep)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    combinations = list(itertools.product(args.workers, args.particles, args.pixels))
    reports = []
    for workers, particles, pixels in combinations:
        case = from_flags(
            LoadCaseConfig,
            dict(
                particles=particles,
                pixels=pixels,
                workers=workers,
                camera_rate=args.camera_rate,
                odometry_rate=args.odometry_rate,
                duration=args.duration,
                warmup=args.warmup,
                map=args.map,
                device=args.device,
                seed=args.seed,
                prerender=not args.render_live,
                overload=args.overload,
                memory_period=args.memory_period,
            ),
            {"prerender": "--render-live"},
        )
        report = run_case(case, args.out / f"w{workers}_p{particles}_m{pixels}")
        reports.append(report)
        if not args.json:
            print(format_table(report), flush=True)
    if len(reports) > 1:
        files = {"csv": str(write_sweep_csv(reports, args.out / "sweep.csv")), "png": str(plot_sweep(reports, args.out / "sweep.png"))}
        print(json.dumps({"cases": reports, "files": files}) if args.json else json.dumps(files), flush=True)
    elif args.json:
        print(json.dumps(reports[0]), flush=True)
    return 0 if all(r["lost_messages"] == 0 for r in reports) else 1
