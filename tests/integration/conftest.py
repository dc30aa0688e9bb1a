"""Real service processes on loopback Zenoh: a hub session in the test, services connecting to it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus, PoseEstimate, PoseStamped, UpdateResult
from services.transport import TransportConfig, open_bus
from tests.services.helpers import free_port, wait_until

ROBOT = "itest"
REPO = Path(__file__).resolve().parents[2]


class Observer:
    """Everything the services publish that the tests look at, collected by the hub's callbacks."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.poses: list[PoseEstimate] = []
        self.pose_arrivals: list[float] = []  # monotonic seconds at which each pose arrived
        self.truth: dict[float, PoseStamped] = {}
        self.status: FilterStatus | None = None
        self.statuses = 0  # status messages received
        self.results: list[UpdateResult] = []
        self.undecodable = 0

    def on(self, kind: str, payload: bytes) -> None:
        try:
            self._store(kind, payload)
        except DecodeError:
            self.undecodable += 1  # the tests' own garbage

    def _store(self, kind: str, payload: bytes) -> None:
        with self.lock:
            if kind == "pose":
                self.poses.append(decode(payload, PoseEstimate))
                self.pose_arrivals.append(time.monotonic())
            elif kind == "truth":
                message = decode(payload, PoseStamped)
                self.truth[message.stamp] = message
            elif kind == "status":
                self.status = decode(payload, FilterStatus)
                self.statuses += 1
            else:
                self.results.append(decode(payload, UpdateResult))

    def counter(self, name: str) -> int:
        return 0 if self.status is None else self.status.counters.get(name, 0)

    def workers(self) -> list[str]:
        return [] if self.status is None else self.status.workers


class Stack:
    """Starts and stops `locnerf run …` processes connected to the hub."""

    def __init__(self, endpoint: str, logs: Path) -> None:
        self.endpoint = endpoint
        self.logs = logs
        self.processes: dict[str, subprocess.Popen] = {}
        self.environment = os.environ | {
            "LOCNERF_ZENOH_MODE": "peer",
            "LOCNERF_ZENOH_CONNECT": endpoint,
            "LOCNERF_ZENOH_LISTEN": "tcp/127.0.0.1:0",
            "PYTHONPATH": str(REPO),
        }

    def start(self, name: str, *arguments: str, environment: dict[str, str] | None = None) -> subprocess.Popen:
        command = [sys.executable, "-m", "cli.main", "-v", *arguments]
        log = open(self.logs / f"{name}.log", "a")
        process = subprocess.Popen(command, env=environment or self.environment, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        log.close()
        self.processes[name] = process
        return process

    def kill(self, name: str) -> None:
        process = self.processes.pop(name)
        process.kill()
        process.wait()

    def stop_all(self) -> None:
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for name, process in self.processes.items():
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.processes.clear()

    def log_tail(self) -> str:
        return "\n".join(f"== {path.name}\n" + "\n".join(path.read_text().splitlines()[-15:]) for path in sorted(self.logs.glob("*.log")))


def watch(bus) -> Observer:
    """An Observer fed by ``bus``'s subscriptions to the poses, ground truth, status and results."""
    observer = Observer()
    topics = {"pose": keys.POSE, "truth": keys.GROUND_TRUTH, "status": keys.STATUS, "result": keys.UPDATE_RESULT}
    for kind, topic in topics.items():
        bus.subscribe(keys.key(ROBOT, topic), lambda _k, payload, kind=kind: observer.on(kind, payload))
    return observer


@pytest.fixture
def hub(tmp_path) -> Iterator[tuple[Stack, Observer, object]]:
    """(stack, observer, hub bus): a listening hub session and a process launcher."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_bus(TransportConfig(listen=(endpoint,)))
    observer = watch(bus)
    logs = tmp_path / "logs"
    logs.mkdir()
    stack = Stack(endpoint, logs)
    try:
        yield stack, observer, bus
    finally:
        stack.stop_all()
        bus.close()


def wait_for(condition, timeout: float, what: str, stack: Stack) -> None:
    """wait_until, with the services' log tails in the failure message."""
    try:
        wait_until(condition, timeout, what, poll=0.1)
    except AssertionError as error:
        raise AssertionError(f"{error}\n{stack.log_tail()}") from None


__all__ = ["ROBOT", "Observer", "Stack", "wait_for", "watch"]
