"""Real service processes on loopback Zenoh: a hub session in the test, services connecting to it."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import FilterStatus, PoseEstimate, PoseStamped, UpdateResult
from locnerf_services.local_hub import LocalHub
from locnerf_services.supervisor import ServiceProcess, Supervisor
from tests.services.helpers import wait_until

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
    """Starts and stops `locnerf …` processes connected to the hub, through the hub's supervisor."""

    def __init__(self, hub: LocalHub) -> None:
        self.endpoint = hub.endpoint
        self.supervisor: Supervisor = hub.supervisor

    @property
    def environment(self) -> dict[str, str]:
        """The environment of the services: peers of the hub."""
        return self.supervisor.environment

    @property
    def processes(self) -> dict[str, ServiceProcess]:
        """The running processes by name."""
        return self.supervisor.processes

    def start(self, name: str, *arguments: str, environment: dict[str, str] | None = None) -> ServiceProcess:
        """``locnerf -v <arguments>`` as ``name``."""
        return self.supervisor.start(name, [sys.executable, "-m", "locnerf_cli.main", "-v", *arguments], environment)

    def kill(self, name: str) -> None:
        self.supervisor.kill(name)

    def log_tail(self) -> str:
        return self.supervisor.log_tail()


def watch(bus) -> Observer:
    """An Observer fed by ``bus``'s subscriptions to the poses, ground truth, status and results."""
    observer = Observer()
    topics = {"pose": keys.POSE, "truth": keys.GROUND_TRUTH, "status": keys.STATUS, "result": keys.UPDATE_RESULT}
    for kind, topic in topics.items():
        bus.subscribe(keys.key(ROBOT, topic), lambda _k, payload, kind=kind: observer.on(kind, payload))
    return observer


@contextlib.contextmanager
def open_hub(folder: Path) -> Iterator[tuple[Stack, Observer, object]]:
    """(stack, observer, hub bus): a listening hub session and a process launcher, logs in ``folder``/logs;
    the services still running are stopped on exit."""
    with LocalHub(folder / "logs", stop_timeout=20.0, environment=os.environ | {"PYTHONPATH": str(REPO)}, cwd=REPO) as hub:
        yield Stack(hub), watch(hub.bus), hub.bus


@pytest.fixture
def hub(tmp_path) -> Iterator[tuple[Stack, Observer, object]]:
    """(stack, observer, hub bus) of :func:`open_hub`, for one test."""
    with open_hub(tmp_path) as opened:
        yield opened


def wait_for(condition, timeout: float, what: str, stack: Stack) -> None:
    """wait_until, with the services' log tails in the failure message."""
    try:
        wait_until(condition, timeout, what, poll=0.1)
    except AssertionError as error:
        raise AssertionError(f"{error}\n{stack.log_tail()}") from None


__all__ = ["ROBOT", "Observer", "Stack", "open_hub", "wait_for", "watch"]
