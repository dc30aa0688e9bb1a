"""Python modules run as service processes forked from a warm fork server, so that none imports torch again.

A service process spends most of its start importing torch (2.3 of the 3.1 s a filter takes to import on a 2-core
machine), and a live run starts four or five of them at once. :func:`start_module` runs ``python -m MODULE ARGS``
instead in a child of Python's ``forkserver`` (:mod:`multiprocessing`), which imports :data:`PRELOADED` once per
parent process: each later service starts in milliseconds, as its own process with its own pid, environment,
working directory and log file, and reads its configuration afresh.

Only modules whose import starts no thread are preloaded: a fork copies the thread that forks and no other, so
OpenCV (its import starts one) is imported by the services that use it, in their own process. numpy's OpenBLAS
threads are re-created after a fork by OpenBLAS itself.
"""

from __future__ import annotations

import multiprocessing
import os
import runpy
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

PRELOADED = ("torch", "locnerf_services.filter_loop.service", "locnerf_services.nerf_worker.service")
"""Modules the fork server imports before it forks any service."""

_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(list(PRELOADED))


def module_of(command: Sequence[str]) -> str | None:
    """MODULE of a command line ``[sys.executable, "-m", MODULE, ...]``; None for any other command."""
    if len(command) >= 3 and command[0] == sys.executable and command[1] == "-m":
        return command[2]
    return None


def can_fork_here() -> bool:
    """False inside a process this module started: it is a daemon, and a daemon's children would be
    stopped with it; its own services then start with :class:`subprocess.Popen`."""
    return not multiprocessing.current_process().daemon


class WarmProcess:
    """A process started by :func:`start_module`, with the part of :class:`subprocess.Popen` the supervisor and
    its callers use: ``pid``, ``args``, ``returncode``, ``poll``, ``wait``, ``send_signal``, ``terminate``, ``kill``.
    A process killed by signal N returns -N, as with Popen."""

    def __init__(self, process: multiprocessing.process.BaseProcess, args: list[str]) -> None:
        self._process = process
        self.args = args
        self.pid: int = process.pid

    @property
    def returncode(self) -> int | None:
        """The exit code once the process has exited (after :meth:`poll` or :meth:`wait`), else None."""
        return self._process.exitcode

    def poll(self) -> int | None:
        """The exit code if the process has exited, else None (does not block)."""
        return self._process.exitcode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the exit code.

        Raises:
            subprocess.TimeoutExpired: still running after ``timeout`` seconds.
        """
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return self._process.exitcode

    def send_signal(self, signum: int) -> None:
        """Send ``signum`` unless the process has exited."""
        if self.poll() is None:
            os.kill(self.pid, signum)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def _run_in_child(module: str, arguments: list[str], environment: dict[str, str], log: str, append: bool, cwd: str | None) -> None:
    """In the forked child: output to ``log``, the given environment and working directory, then ``module`` as ``__main__``."""
    descriptor = os.open(log, os.O_WRONLY | os.O_CREAT | (os.O_APPEND if append else os.O_TRUNC), 0o644)
    os.dup2(descriptor, 1)
    os.dup2(descriptor, 2)
    os.close(descriptor)
    os.environ.clear()
    os.environ.update(environment)
    if cwd is not None:
        os.chdir(cwd)
    sys.argv = [module, *arguments]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


def start_module(
    module: str, arguments: Sequence[str], environment: Mapping[str, str], log: Path, append: bool = False, cwd: Path | None = None
) -> WarmProcess:
    """``python -m module arguments`` forked from the warm server, its stdout and stderr in ``log`` (appended to when
    ``append``), in ``environment`` and ``cwd`` (default: this process's working directory).

    The process is a daemon of this one: were it still running when this process exits, it gets SIGTERM then.
    """
    process = _CONTEXT.Process(
        target=_run_in_child,
        args=(module, list(arguments), dict(environment), str(log), append, None if cwd is None else str(cwd)),
        name=module,
        daemon=True,
    )
    process.start()
    return WarmProcess(process, [sys.executable, "-m", module, *arguments])
