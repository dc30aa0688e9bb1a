"""Services forked from the warm server behave as the same ``python -m`` command started by Popen."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from locnerf_services.supervisor import Supervisor
from locnerf_services.warm_start import WarmProcess, module_of, start_module
from tests.services.helpers import wait_until

CHILD = "tests.services.warm_child"
REPO = Path(__file__).resolve().parents[2]


def test_only_python_dash_m_command_lines_name_a_module():
    assert module_of([sys.executable, "-m", CHILD, "0"]) == CHILD
    assert module_of([sys.executable, "-u", "-m", CHILD]) is None
    assert module_of(["python3.11", "-m", CHILD]) is None
    assert module_of([sys.executable, "-c", "pass"]) is None


def test_a_warm_child_gets_its_arguments_environment_directory_and_log_and_exits_with_its_code(tmp_path):
    """The same command through the supervisor both ways (``-u`` keeps it a Popen): the same log, the same code."""
    folder = tmp_path / "work"
    folder.mkdir()
    logs = {}
    for way, flags in (("warm", []), ("popen", ["-u"])):
        supervisor = Supervisor(tmp_path / way, environment={"LOCNERF_WARM_PROBE": "seen", "PYTHONPATH": str(REPO)}, cwd=folder)
        process = supervisor.start("child", [sys.executable, *flags, "-m", CHILD, "7", "x y"])
        assert isinstance(process, WarmProcess) == (way == "warm")
        assert process.wait(timeout=60) == 7 and process.returncode == 7 and process.poll() == 7
        logs[way] = (tmp_path / way / "child.log").read_text()
    assert logs["warm"] == logs["popen"] == f"argv ['7', 'x y'] cwd {folder} probe seen\nto stderr\n"


def test_an_uncaught_error_exits_1_with_its_traceback_in_the_log(tmp_path):
    process = start_module(CHILD, ["raise"], {}, tmp_path / "child.log")
    assert process.wait(timeout=60) == 1
    assert "RuntimeError: an uncaught error in the child" in (tmp_path / "child.log").read_text()


def test_signals_reach_the_child_and_a_killed_child_returns_minus_the_signal(tmp_path):
    log = tmp_path / "child.log"

    def readies() -> int:
        return log.read_text().count("ready") if log.is_file() else 0

    polite = start_module(CHILD, ["0", "polite"], {}, log)
    wait_until(lambda: readies() == 1, 60, "the child's SIGTERM handler")
    with pytest.raises(subprocess.TimeoutExpired):
        polite.wait(timeout=0.2)
    polite.terminate()
    assert polite.wait(timeout=60) == 3
    second = start_module(CHILD, ["0", "polite"], {}, log, append=True)
    wait_until(lambda: readies() == 2, 60, "the second child")
    second.kill()
    assert second.wait(timeout=60) == -signal.SIGKILL
    second.kill()  # no error once it has exited
    assert log.read_text().count("argv") == 2, "appended, not truncated"
