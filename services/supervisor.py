"""Service processes on one machine: start them with a config file, watch them, stop them.

A :class:`Supervisor` starts ``python -m services.<package> --config FILE`` (or any command line)
with its output in ``<logs>/<name>.log``, reports the ones that exited, and stops them all: SIGTERM
in the reverse order of their start (the ingest, started last, stops first), then SIGKILL for those
still running after ``stop_timeout`` seconds. Exit codes are kept by name. Config files are the
pydantic config models dumped to TOML (:func:`write_config`), never text built by hand.

``python -m`` command lines are forked from a warm server that has imported torch once
(:mod:`locnerf_services.warm_start`): each is still a process of its own, started in milliseconds instead of
seconds. Other command lines start as a :class:`subprocess.Popen`.

``locnerf up``, ``loadtest``, ``fuzz``, ``eval tracking --live`` and the integration tests start
their services through it.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import tomli_w
from pydantic import BaseModel

from locnerf_services.transport.config import ENV_CONNECT, ENV_LISTEN, ENV_MODE
from locnerf_services.warm_start import WarmProcess, can_fork_here, module_of, start_module

logger = logging.getLogger(__name__)

SERVICE_PACKAGES = {
    "ingest": "locnerf_services.sensor_ingest",
    "filter": "locnerf_services.filter_loop",
    "worker": "locnerf_services.nerf_worker",
    "router": "locnerf_services.router",
}
"""The package run by ``python -m`` for each kind of service."""

ServiceProcess = subprocess.Popen | WarmProcess
"""A started process: ``python -m`` commands are forked warm (locnerf_services.warm_start), any other is a Popen."""

STOP_TIMEOUT_S = 15.0
"""Seconds between SIGTERM and SIGKILL when stopping."""


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def loopback_environment(endpoint: str, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) with the Zenoh settings of a peer that
    connects to ``endpoint`` and listens on a free loopback port."""
    return dict(os.environ if base is None else base) | {ENV_MODE: "peer", ENV_CONNECT: endpoint, ENV_LISTEN: "tcp/127.0.0.1:0"}


def config_toml(config: BaseModel) -> str:
    """The fields of ``config`` that differ from their defaults, as a TOML document that the
    model reads back equal to ``config``.

    Raises:
        ValueError: a field set to None where its default is not None (TOML has no null).
    """
    data = config.model_dump(mode="json", exclude_defaults=True)
    try:
        return tomli_w.dumps(data)
    except TypeError as error:
        raise ValueError(f"{type(config).__name__} {data}: not writable as TOML ({error}); expected no None values besides defaults") from None


def write_config(path: Path, config: BaseModel) -> Path:
    """Write ``config`` as TOML (see :func:`config_toml`) to ``path``, creating its folder; returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(config_toml(config))
    return path


def service_command(service: str, config_file: Path) -> list[str]:
    """The command line of a ``service`` (``ingest``, ``filter``, ``worker`` or ``router``) reading ``config_file``."""
    if service not in SERVICE_PACKAGES:
        raise ValueError(f"service {service!r}: expected one of {sorted(SERVICE_PACKAGES)}")
    return [sys.executable, "-m", SERVICE_PACKAGES[service], "--config", str(config_file)]


class Supervisor:
    """Child processes by name, their logs in ``logs``, stopped together.

    Args:
        logs: folder for ``<name>.log`` (output of the process) and ``<name>.toml`` (its config).
        environment: environment of the processes (default: this process's).
        stop_timeout: seconds between SIGTERM and SIGKILL in :meth:`stop_all`.
        cwd: working directory of the processes (default: this process's).
    """

    def __init__(self, logs: Path, environment: Mapping[str, str] | None = None, stop_timeout: float = STOP_TIMEOUT_S, cwd: Path | None = None) -> None:
        if stop_timeout <= 0:
            raise ValueError(f"stop_timeout {stop_timeout}: expected > 0 seconds")
        self.logs = logs
        self.environment = dict(os.environ if environment is None else environment)
        self.stop_timeout = stop_timeout
        self.cwd = cwd
        self.processes: dict[str, ServiceProcess] = {}
        self.exit_codes: dict[str, int] = {}
        self._started: set[str] = set()
        logs.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, command: Sequence[str], environment: Mapping[str, str] | None = None) -> ServiceProcess:
        """Run ``command`` as ``name``, its output in ``<logs>/<name>.log`` (appended when ``name`` ran before).

        Raises:
            ValueError: ``name`` is already running.
        """
        if name in self.processes and self.processes[name].poll() is None:
            raise ValueError(f"service {name!r}: already running (pid {self.processes[name].pid}); expected a new name")
        log_path, append, env = self.logs / f"{name}.log", name in self._started, dict(environment or self.environment)
        module = module_of(command)
        if module is not None and can_fork_here():
            process: ServiceProcess = start_module(module, command[3:], env, log_path, append=append, cwd=self.cwd)
        else:
            with open(log_path, "a" if append else "w") as log:
                process = subprocess.Popen(list(command), env=env, stdout=log, stderr=subprocess.STDOUT, cwd=self.cwd)
        self.processes[name] = process
        self._started.add(name)
        self.exit_codes.pop(name, None)
        logger.info("started %s (pid %d): %s", name, process.pid, " ".join(command))
        return process

    def start_service(self, name: str, service: str, config: BaseModel, environment: Mapping[str, str] | None = None) -> ServiceProcess:
        """Write ``config`` to ``<logs>/<name>.toml`` and run ``python -m services.<service> --config`` it as ``name``."""
        return self.start(name, service_command(service, write_config(self.logs / f"{name}.toml", config)), environment)

    def exited(self) -> dict[str, int]:
        """Exit codes of the processes that are no longer running, by name."""
        for name, process in self.processes.items():
            if process.poll() is not None:
                self.exit_codes[name] = process.returncode
        return {name: self.exit_codes[name] for name in self.processes if name in self.exit_codes}

    def check_running(self, allowed_to_exit: Sequence[str] = ()) -> None:
        """Raise RuntimeError naming the services that exited (those in ``allowed_to_exit`` only with an error)."""
        failed = {name: code for name, code in self.exited().items() if name not in allowed_to_exit or code != 0}
        if failed:
            raise RuntimeError(f"service(s) exited early with codes {failed}: see the logs in {self.logs}")

    def kill(self, name: str) -> int:
        """SIGKILL ``name`` and forget it; its exit code."""
        process = self.processes.pop(name)
        process.kill()
        self.exit_codes[name] = process.wait()
        return self.exit_codes[name]

    def stop_all(self) -> dict[str, int]:
        """SIGTERM every running process (last started first), SIGKILL those still running
        ``stop_timeout`` seconds later; the exit codes of all of them by name (SIGKILL: -9)."""
        running = [(name, p) for name, p in reversed(self.processes.items()) if p.poll() is None]
        for _name, process in running:
            process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.stop_timeout
        for name, process in running:
            try:
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                logger.warning("%s did not stop within %.0f s of SIGTERM: killing it", name, self.stop_timeout)
                process.kill()
                process.wait()
        codes = self.exited()
        self.processes.clear()
        return codes

    def log_tail(self, lines: int = 15) -> str:
        """The last ``lines`` lines of every log, each under a ``== <file>`` header."""
        return "\n".join(f"== {path.name}\n" + "\n".join(path.read_text().splitlines()[-lines:]) for path in sorted(self.logs.glob("*.log")))
