"""``locnerf fuzz``: throw hostile payloads at every subscribed key of running services, then check them.

Starts a filter, a NeRF worker (``fuzzed``), a streaming ingest (odometry only, so that every
image the filter sees is a hostile one) and a second ingest that waits for workers (the only time
an ingest subscribes to anything: ``filter/status``), all on loopback Zenoh like ``locnerf up``.
For each target of :data:`locnerf.eval.fuzz_payloads.TARGETS` it publishes ``--payloads``
Hypothesis-drawn payloads (seeded, no example database) at up to ``--rate`` per second, waits
until the service's status counters settle, and compares them with what was sent, kind by kind.

Afterwards it checks that every process is alive, that the counts agree (every payload counted
under its kind, or under the service's drop counters: a full inbox, an image replaced by a newer
one before it was read), that no process's resident memory grew by more than ``--rss-bound-mb``,
and that the pose stream kept the odometry rate (every odometry stamp gave a pose; pose rate within
``--rate-tolerance`` of 15 Hz). A table, or JSON with ``--json``; exit status 1 on any failure.
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import psutil
from hypothesis import HealthCheck, Phase, given, seed, settings
from pydantic import BaseModel

from locnerf.errors import LocnerfInputError
from locnerf.eval.fuzz_payloads import ACCEPTED, TARGETS, FuzzTarget, Hostile
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus, PoseEstimate, ServiceStatus
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.local_hub import LocalHub
from locnerf_services.nerf_worker.__main__ import WorkerConfig
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.transport import TransportConfig

logger = logging.getLogger(__name__)

ODOMETRY_RATE_HZ = 15.0
STARTUP_TIMEOUT_S = 180.0
SETTLE_TIMEOUT_S = 20.0
WAITING_INGEST = "waiting"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf fuzz``."""
    parser.add_argument("--payloads", type=int, default=10_000, help="payloads per subscribed key")
    parser.add_argument("--rate", type=float, default=1000.0, help="payloads per second at most")
    parser.add_argument("--seed", type=int, default=0, help="seed of the Hypothesis draws")
    parser.add_argument("--rss-bound-mb", type=float, default=50.0, help="largest accepted growth of a process's resident memory, MB")
    parser.add_argument("--rate-tolerance", type=float, default=0.05, help="largest accepted relative deviation of the pose rate from 15 Hz")
    parser.add_argument("--only", default="", help="comma-separated key suffixes to fuzz (default: all)")
    parser.add_argument("--out", type=Path, default=Path("out/fuzz"), help="folder for the services' configs and logs")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.set_defaults(func=run)


@dataclass
class Observations:
    """What the fuzzer reads back from the bus: latest statuses and pose arrivals."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    filter: dict[str, int] = field(default_factory=dict)
    filter_workers: list[str] = field(default_factory=list)
    services: dict[str, dict[str, int]] = field(default_factory=dict)
    poses: list[tuple[float, float]] = field(default_factory=list)

    def on_status(self, payload: bytes) -> None:
        try:
            status = decode(payload, FilterStatus)
        except DecodeError:
            return  # the fuzzer's own garbage on filter/status
        with self.lock:
            self.filter, self.filter_workers = status.counters, status.workers

    def on_service(self, payload: bytes) -> None:
        status = decode(payload, ServiceStatus)
        with self.lock:
            self.services["worker" if status.service == "nerf_worker" else status.instance] = status.counters

    def on_pose(self, payload: bytes) -> None:
        stamp = decode(payload, PoseEstimate).stamp
        with self.lock:
            self.poses.append((time.monotonic(), stamp))

    def counters(self, service: str) -> dict[str, int]:
        """The latest counters of ``filter``, ``worker`` or the waiting ``ingest`` (empty before its first status)."""
        with self.lock:
            if service == "filter":
                return dict(self.filter)
            return dict(self.services.get("worker" if service == "worker" else WAITING_INGEST, {}))


class MemoryWatch:
    """Reads every process's resident memory every ``period`` seconds on a thread (start, max, end)."""

    def __init__(self, pids: dict[str, int], period: float = 0.5) -> None:
        self.processes = {name: psutil.Process(pid) for name, pid in pids.items()}
        self.readings: dict[str, list[float]] = {name: [] for name in pids}
        self._stop = threading.Event()
        self._period = period
        self._read()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for name, process in self.processes.items():
            self.readings[name].append(process.memory_info().rss / 2**20)

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            self._read()

    def stop(self) -> dict[str, dict[str, float]]:
        """Stop reading; per process: start, max, end, growth (end − start), MB."""
        self._stop.set()
        self._thread.join()
        self._read()
        return {
            name: {"start_mb": round(r[0], 1), "max_mb": round(max(r), 1), "end_mb": round(r[-1], 1), "growth_mb": round(r[-1] - r[0], 1)}
            for name, r in self.readings.items()
        }


def publish_payloads(target: FuzzTarget, count: int, rate: float, base_seed: int, send) -> collections.Counter[tuple[str, str]]:
    """Draw at least ``count`` payloads for ``target`` with Hypothesis and ``send`` each one.

    A ``@given`` function runs under ``settings(max_examples=count, database=None, phases=[generate])``
    with an explicit seed; Hypothesis may stop before ``count`` distinct examples, so it runs again
    with the next seed until ``count`` were sent. Returns counts by (damage, expected kind)."""
    sent: collections.Counter[tuple[str, str]] = collections.Counter()
    period = 1.0 / rate
    next_at = [time.monotonic()]

    def throw(hostile: Hostile) -> None:
        if sum(sent.values()) >= count:
            return
        delay = next_at[0] - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        next_at[0] = max(next_at[0] + period, time.monotonic() - 10 * period)
        send(hostile.payload)
        sent[(hostile.damage, hostile.kind)] += 1

    round_seed = base_seed
    while sum(sent.values()) < count:
        runner = settings(
            max_examples=count - sum(sent.values()), database=None, phases=[Phase.generate], deadline=None, suppress_health_check=list(HealthCheck)
        )(seed(round_seed)(given(target.payloads)(throw)))
        runner()
        round_seed += 1_000_003
    return sent


def compare_counts(target: FuzzTarget, sent: collections.Counter[tuple[str, str]], before: dict[str, int], after: dict[str, int]) -> dict[str, object]:
    """Sent vs counted, by counter. Agreement: no payload accepted, no counter beyond its expected count,
    no bad-message counter that nothing was sent for, and every payload counted or dropped by design."""
    expected: collections.Counter[str] = collections.Counter()
    for (_damage, kind), n in sent.items():
        expected[target.counter(kind)] += n
    delta = {name: after.get(name, 0) - before.get(name, 0) for name in set(after) | set(before)}
    bad = {name: n for name, n in delta.items() if name.startswith("bad_") and name != "bad_messages" and n}
    drops = sum(delta.get(name, 0) for name in target.drop_counters)
    counted = sum(bad.values())
    total = sum(sent.values())
    over = {name: (bad.get(name, 0), n) for name, n in expected.items() if bad.get(name, 0) > n}
    unexpected = {name: n for name, n in bad.items() if name not in expected}
    accepted = sum(n for (_d, kind), n in sent.items() if kind == ACCEPTED)
    agree = not over and not unexpected and accepted == 0 and counted + drops == total
    return {
        "sent": total,
        "counted": counted,
        "dropped_by_design": drops,
        "expected_by_counter": dict(expected),
        "counted_by_counter": {name: bad.get(name, 0) for name in sorted(set(expected) | set(bad))},
        "unexpected_counters": unexpected,
        "other_counter_changes": {name: n for name, n in sorted(delta.items()) if n and not name.startswith("bad_")},
        "accepted": accepted,
        "agree": agree,
    }


def service_configs(robot: str) -> dict[str, tuple[str, BaseModel]]:
    """The fuzzed processes by log name: (service, configuration).

    The streaming ingest sends odometry only (``image_rate = 0``), so no image of the stream
    competes with the hostile ones; the waiting ingest waits for a thousand
    workers for a day, subscribed to the filter status all along.
    """
    on_cpu = {"robot_id": robot, "map": "world", "device": "cpu"}
    return {
        "filter": ("filter", FilterProcessConfig(**on_cpu)),
        "worker": ("worker", WorkerConfig(worker_id="fuzzed", **on_cpu)),
        "ingest": ("ingest", IngestConfig(robot_id=robot, ingest_id="stream", world={"image_rate": 0.0, "duration": 86400.0})),
        "ingest_waiting": ("ingest", IngestConfig(robot_id=robot, ingest_id=WAITING_INGEST, wait_for_workers=1000, wait_timeout=86400.0)),
    }


def _wait(condition, timeout: float, what: str, supervisor) -> None:
    """Poll ``condition`` while every process of ``supervisor`` runs; RuntimeError after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        supervisor.check_running()
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout:.0f} s waiting for {what}: see the logs in {supervisor.logs}")
        time.sleep(0.1)


def _settle(observations: Observations, target: FuzzTarget, total: int, before: dict[str, int], supervisor) -> dict[str, int]:
    """Counters once they account for ``total`` payloads, or once two statuses in a row did not change."""
    interesting = lambda c: sum(n for k, n in c.items() if k.startswith("bad_") and k != "bad_messages") + sum(c.get(k, 0) for k in target.drop_counters)  # noqa: E731
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    last, unchanged_since = None, time.monotonic()
    while time.monotonic() < deadline:
        counters = observations.counters(target.service)
        if interesting(counters) - interesting(before) >= total:
            return counters
        if counters != last:
            last, unchanged_since = counters, time.monotonic()
        elif time.monotonic() - unchanged_since > 2.5:
            return counters
        supervisor.check_running()
        time.sleep(0.2)
    return observations.counters(target.service)


def pose_stream(poses: list[tuple[float, float]], start: float, end: float) -> dict[str, float]:
    """Pose rate over [start, end] (arrival times) and odometry stamps skipped (gaps in the pose stamps)."""
    inside = [stamp for at, stamp in poses if start <= at <= end]
    skipped = sum(max(0, round((b - a) * ODOMETRY_RATE_HZ) - 1) for a, b in zip(inside, inside[1:]))
    return {"poses": len(inside), "pose_rate_hz": round(len(inside) / (end - start), 3) if end > start else 0.0, "odometry_stamps_without_pose": skipped}


def run_fuzz(args: argparse.Namespace) -> dict[str, object]:
    """Start the services, fuzz every target, return the report (see the module docstring)."""
    robot = "fuzz"
    transport_config = TransportConfig(block_when_congested=True)
    hub = LocalHub(args.out, transport=transport_config)
    observations = Observations()
    hub.subscribe(keys.key(robot, keys.STATUS), lambda _k, p: observations.on_status(p))
    hub.subscribe(keys.key(robot, keys.WORKER_STATUS, worker_id="*"), lambda _k, p: observations.on_service(p))
    hub.subscribe(keys.key(robot, keys.INGEST_STATUS, ingest_id="*"), lambda _k, p: observations.on_service(p))
    hub.subscribe(keys.key(robot, keys.POSE), lambda _k, p: observations.on_pose(p))
    targets = [t for t in TARGETS if not args.only or t.topic.suffix in args.only.split(",")]
    supervisor = hub.supervisor
    results = []
    try:
        for name, (service, config) in service_configs(robot).items():
            supervisor.start_service(name, service, config)

        def ready() -> bool:
            with observations.lock:
                seen = bool(observations.poses) and "fuzzed" in observations.filter_workers
            return seen and all(observations.counters(s) for s in ("worker", "ingest"))

        _wait(ready, STARTUP_TIMEOUT_S, "the first pose and the statuses of filter, worker and waiting ingest", supervisor)
        watch = MemoryWatch({name: p.pid for name, p in supervisor.processes.items()})
        started = time.monotonic()
        for target in targets:
            before = observations.counters(target.service)
            key = target.key(robot)
            sent = publish_payloads(target, args.payloads, args.rate, args.seed, lambda payload, key=key: hub.bus.publish(key, payload))
            after = _settle(observations, target, sum(sent.values()), before, supervisor)
            results.append(
                {"service": target.service, "key": target.topic.suffix, "by_damage": {f"{d} -> {k}": n for (d, k), n in sorted(sent.items())}}
                | compare_counts(target, sent, before, after)
            )
            logger.info("%s %s: %s", target.service, target.topic.suffix, {k: results[-1][k] for k in ("sent", "counted", "dropped_by_design", "agree")})
        ended = time.monotonic()
        memory = watch.stop()
        exited = supervisor.exited()
        alive = {name: name not in exited for name in supervisor.processes}
    finally:
        hub.close()
    with observations.lock:
        stream = pose_stream(observations.poses, started, ended)
    rate_ok = abs(stream["pose_rate_hz"] - ODOMETRY_RATE_HZ) <= args.rate_tolerance * ODOMETRY_RATE_HZ and stream["odometry_stamps_without_pose"] == 0
    memory_ok = all(m["growth_mb"] <= args.rss_bound_mb for m in memory.values())
    return {
        "payloads_per_key": args.payloads,
        "seed": args.seed,
        "seconds": round(ended - started, 1),
        "targets": results,
        "alive": alive,
        "memory_mb": memory,
        "rss_bound_mb": args.rss_bound_mb,
        "pose_stream": stream,
        "checks": {"alive": all(alive.values()), "counts_agree": all(r["agree"] for r in results), "memory_bounded": memory_ok, "pose_rate_held": rate_ok},
    }


def format_report(report: dict[str, object]) -> str:
    """The readable form of a report."""
    lines = [f"{'service':<8} {'key':<30} {'damage -> counted as':<44} {'sent':>6}"]
    for target in report["targets"]:
        for damage, n in target["by_damage"].items():
            lines.append(f"{target['service']:<8} {target['key']:<30} {damage:<44} {n:>6}")
        verdict = "agree" if target["agree"] else "DISAGREE"
        lines.append(
            f"{'':<8} {'':<30} {'total: sent / counted / dropped by design':<44} {target['sent']:>6} / {target['counted']} / {target['dropped_by_design']}  {verdict}"
        )
        for name, n in target["counted_by_counter"].items():
            lines.append(f"{'':<8} {'':<30}   {name:<42} expected {target['expected_by_counter'].get(name, 0):>6}, counted {n:>6}")
    lines.append("memory (MB): " + ", ".join(f"{name} {m['start_mb']} -> max {m['max_mb']} -> {m['end_mb']}" for name, m in report["memory_mb"].items()))
    lines.append(f"pose stream: {report['pose_stream']}")
    lines.append(f"checks: {report['checks']} ({report['seconds']} s)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.payloads < 1 or args.rate <= 0:
        raise LocnerfInputError(f"--payloads {args.payloads}, --rate {args.rate}: expected >= 1 and > 0")
    report = run_fuzz(args)
    print(json.dumps(report) if args.json else format_report(report), flush=True)
    return 0 if all(report["checks"].values()) else 1
