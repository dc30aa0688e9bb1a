"""Plumbing shared by the service processes: bad-message accounting, rates, stop signals."""

from __future__ import annotations

import argparse
import collections
import logging
import os
import signal
import socket
import sys
import threading
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from locnerf.errors import ConfigError
from locnerf.messages.codec import encode
from locnerf.messages.schemas import ServiceStatus

ConfigModel = TypeVar("ConfigModel", bound=BaseModel)

logger = logging.getLogger(__name__)

ENV_LOG_LEVEL = "LOCNERF_LOG_LEVEL"


def log_level_from_environment() -> int:
    """The services' log level: ``LOCNERF_LOG_LEVEL`` (DEBUG, INFO, WARNING, ERROR; default INFO).

    Raises:
        ConfigError: the variable names no level.
    """
    name = os.environ.get(ENV_LOG_LEVEL, "INFO").strip().upper()
    levels = {"DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARNING": logging.WARNING, "ERROR": logging.ERROR}
    if name not in levels:
        raise ConfigError(f"{ENV_LOG_LEVEL}={os.environ[ENV_LOG_LEVEL]!r}: expected one of {', '.join(levels)}")
    return levels[name]


class BadMessages:
    """Counts dropped messages by kind and logs the first one of each kind with its reason."""

    def __init__(self, service: str) -> None:
        self.service = service
        self.counts: collections.Counter[str] = collections.Counter()

    def record(self, kind: str, reason: str) -> None:
        """Count one bad message; log it if it is the first of its kind."""
        if self.counts[kind] == 0:
            logger.warning("%s: dropping a bad message (%s): %s (further ones are only counted)", self.service, kind, reason)
        self.counts[kind] += 1

    @property
    def total(self) -> int:
        """All bad messages so far."""
        return sum(self.counts.values())


def default_instance_id() -> str:
    """``<hostname>-<pid>`` with key-expression-safe characters (a worker's or ingest's default name)."""
    host = "".join(c if c.isalnum() or c in "-_" else "-" for c in socket.gethostname())
    return f"{host}-{os.getpid()}"


class StatusPublisher:
    """Publishes a worker's or ingest's :class:`ServiceStatus` on ``key`` every ``period`` seconds.

    The counters are those of ``bad`` (``bad_<kind>`` and ``bad_messages``, as in FilterStatus)
    plus the ones passed to :meth:`publish_if_due`.

    Args:
        publish: sends (key, payload), e.g. a bus's ``publish``.
        key: the status key.
        service, instance: who reports.
        bad: the process's bad-message counts.
        period: seconds between two statuses.
        clock: monotonic seconds.
    """

    def __init__(self, publish, key: str, service: str, instance: str, bad: BadMessages, period: float = 1.0, clock=time.monotonic) -> None:
        self._publish = publish
        self.key, self.service, self.instance, self.bad = key, service, instance, bad
        self.period, self.clock = period, clock
        self._last = -float("inf")

    def status(self, counters: dict[str, int]) -> ServiceStatus:
        """The status with ``counters`` and the bad-message counts."""
        every = dict(counters) | {"bad_messages": self.bad.total} | {f"bad_{kind}": n for kind, n in self.bad.counts.items()}
        return ServiceStatus(stamp=time.time(), service=self.service, instance=self.instance, counters=every)

    def publish_if_due(self, counters: dict[str, int], force: bool = False) -> None:
        """Publish the status if ``period`` has passed since the last one (or ``force``)."""
        now = self.clock()
        if force or now - self._last >= self.period:
            self._last = now
            self._publish(self.key, encode(self.status(counters)))


class RateMeter:
    """Events per second over a sliding window.

    Args:
        window: seconds of history.
        clock: monotonic seconds.
    """

    def __init__(self, window: float = 5.0, clock=time.monotonic) -> None:
        self.window = window
        self.clock = clock
        self._times: collections.deque[float] = collections.deque()

    def tick(self) -> None:
        """Record one event now."""
        now = self.clock()
        self._times.append(now)
        while self._times and now - self._times[0] > self.window:
            self._times.popleft()

    def rate(self) -> float:
        """Events per second in the window (0 with fewer than two events)."""
        now = self.clock()
        while self._times and now - self._times[0] > self.window:
            self._times.popleft()
        if len(self._times) < 2:
            return 0.0
        span = self._times[-1] - self._times[0]
        return (len(self._times) - 1) / span if span > 0 else 0.0


LATENCY_SWITCH_INTERVAL_S = 0.0005
"""GIL switch interval of the processes on the pose path (CPython's default is 5 ms)."""


def prefer_latency_over_throughput() -> None:
    """Let a waiting thread take the GIL after at most ``LATENCY_SWITCH_INTERVAL_S``.

    The filter and the ingest run a latency-bound thread (pose, odometry release) beside threads
    that compute (merges, frame rendering): with the default 5 ms interval the latency-bound
    thread could wait that long for the interpreter after its wake-up.
    """
    sys.setswitchinterval(LATENCY_SWITCH_INTERVAL_S)


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM, for a clean shutdown of the service loop."""
    stop = threading.Event()

    def handler(signum: int, _frame) -> None:
        logger.info("signal %d: stopping", signum)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def load_service_config(model: type[ConfigModel], path: Path | None, overrides: dict[str, Any]) -> ConfigModel:
    """A service config from an optional TOML file, then non-None command-line ``overrides``.

    Raises:
        FileNotFoundError: a missing file. ConfigError: invalid TOML or fields (message names the file).
    """
    data: dict[str, Any] = {}
    source = "command line"
    if path is not None:
        source = str(path)
        try:
            data = tomllib.loads(Path(path).read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: service configuration file not found") from None
        except tomllib.TOMLDecodeError as error:
            raise ConfigError(f"{path}: not valid TOML ({error})") from error
    data |= {name: value for name, value in overrides.items() if value is not None}
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(f"{source}: invalid {model.__name__}:\n{error}") from error


def limit_torch_threads(threads: int) -> None:
    """Cap torch's intra-op threads: several service processes share few cores, and oversubscribed
    OpenMP threads spin instead of working (a render measured 30× slower with 2 threads on a loaded
    2-core machine)."""
    import torch

    if threads < 1:
        raise ValueError(f"torch_threads {threads}: expected >= 1")
    torch.set_num_threads(threads)


def service_main(
    prog: str,
    description: str | None,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int],
    argv: list[str] | None = None,
) -> int:
    """The ``python -m services.<name>`` entry point of one service: parse ``argv``, log at
    ``LOCNERF_LOG_LEVEL`` (INFO by default), ``run``."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_arguments(parser)
    logging.basicConfig(level=log_level_from_environment(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run(parser.parse_args(argv))
