"""The supervisor: config files dumped from the models, processes started, watched and stopped in order."""

from __future__ import annotations

import logging
import signal
import sys
import tomllib
from pathlib import Path

import pytest
from pydantic import BaseModel, ConfigDict

from locnerf.errors import ConfigError
from locnerf_services.nerf_worker.__main__ import WorkerConfig
from locnerf_services.runtime import ENV_LOG_LEVEL, load_service_config, log_level_from_environment
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.supervisor import Supervisor, config_toml, loopback_environment, service_command, write_config
from locnerf_services.transport import TransportConfig
from tests.services.helpers import wait_until

# A child that writes a line when SIGTERM arrives, then exits 3.
POLITE = (
    "import signal, sys, time\n"
    "def stop(*_):\n"
    "    print('stopped', flush=True)\n"
    "    sys.exit(3)\n"
    "signal.signal(signal.SIGTERM, stop)\n"
    "print('ready', flush=True)\n"
    "time.sleep(60)\n"
)
# A child that ignores SIGTERM.
STUBBORN = "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\nprint('ready', flush=True)\ntime.sleep(60)\n"


def wait_for_line(path: Path, line: str) -> None:
    """Wait until ``path`` holds ``line`` (the child is up and has its handler installed)."""
    wait_until(lambda: line in path.read_text(), 30, f"{line!r} in {path.name}")


def test_a_config_file_holds_the_changed_fields_and_reads_back_equal(tmp_path):
    config = IngestConfig(robot_id="r", source="world", world={"image_rate": 0.0, "duration": 86400.0}, prefetch_events=7)
    path = write_config(tmp_path / "deep" / "ingest.toml", config)
    assert tomllib.loads(path.read_text()) == {"robot_id": "r", "prefetch_events": 7, "world": {"image_rate": 0.0, "duration": 86400.0}}
    assert load_service_config(IngestConfig, path, {}) == config
    worker = WorkerConfig(worker_id="w", transport=TransportConfig(connect=("tcp/127.0.0.1:1",)))
    assert load_service_config(WorkerConfig, write_config(tmp_path / "worker.toml", worker), {}) == worker
    assert config_toml(WorkerConfig()) == ""


def test_a_none_that_is_not_the_default_is_refused():
    class Optional(BaseModel):
        model_config = ConfigDict(frozen=True, extra="forbid")
        value: int | None = 1

    with pytest.raises(ValueError, match=r"Optional \{'value': None\}: not writable as TOML"):
        config_toml(Optional(value=None))


def test_commands_and_environment():
    assert service_command("filter", Path("f.toml")) == [sys.executable, "-m", "locnerf_services.filter_loop", "--config", "f.toml"]
    with pytest.raises(ValueError, match="service 'mapper': expected one of"):
        service_command("mapper", Path("f.toml"))
    environment = loopback_environment("tcp/127.0.0.1:5", {"HOME": "/h"})
    assert environment == {"HOME": "/h", "LOCNERF_ZENOH_MODE": "peer", "LOCNERF_ZENOH_CONNECT": "tcp/127.0.0.1:5", "LOCNERF_ZENOH_LISTEN": "tcp/127.0.0.1:0"}


def test_stop_all_terminates_the_last_started_first_and_kills_what_ignores_sigterm(tmp_path):
    supervisor = Supervisor(tmp_path, stop_timeout=1.0)
    for name in ("first", "second"):
        supervisor.start(name, [sys.executable, "-u", "-c", POLITE])
    supervisor.start("stubborn", [sys.executable, "-u", "-c", STUBBORN])
    for name in ("first", "second", "stubborn"):
        wait_for_line(tmp_path / f"{name}.log", "ready")
    assert supervisor.exited() == {}
    supervisor.check_running()
    signalled = []
    for name, process in supervisor.processes.items():
        send = process.send_signal
        process.send_signal = lambda number, name=name, send=send: (signalled.append((name, number)), send(number))
    codes = supervisor.stop_all()
    assert signalled == [("stubborn", signal.SIGTERM), ("second", signal.SIGTERM), ("first", signal.SIGTERM), ("stubborn", signal.SIGKILL)]
    assert codes == {"first": 3, "second": 3, "stubborn": -signal.SIGKILL}
    assert supervisor.processes == {}
    assert all("stopped" in (tmp_path / f"{name}.log").read_text() for name in ("first", "second"))


def test_exits_are_reported_by_name_with_their_codes(tmp_path):
    supervisor = Supervisor(tmp_path)
    supervisor.start("done", [sys.executable, "-c", "pass"])
    supervisor.start("broken", [sys.executable, "-c", "import sys; print('bad input'); sys.exit(2)"])
    supervisor.start("sleeper", [sys.executable, "-c", "import time; time.sleep(60)"])
    supervisor.processes["done"].wait()
    supervisor.processes["broken"].wait()
    assert supervisor.exited() == {"done": 0, "broken": 2}
    with pytest.raises(RuntimeError, match=r"exited early with codes \{'broken': 2\}"):
        supervisor.check_running(allowed_to_exit=("done",))
    with pytest.raises(RuntimeError, match=r"\{'done': 0, 'broken': 2\}"):
        supervisor.check_running()
    with pytest.raises(ValueError, match="service 'sleeper': already running"):
        supervisor.start("sleeper", [sys.executable, "-c", "pass"])
    assert supervisor.kill("sleeper") == -signal.SIGKILL and "sleeper" not in supervisor.processes
    assert "== broken.log\nbad input" in supervisor.log_tail()
    assert supervisor.stop_all() == {"done": 0, "broken": 2}


def test_a_restarted_service_appends_to_its_log_and_a_new_supervisor_starts_it_afresh(tmp_path):
    for expected in ("one\ntwo\n", "three\n"):
        supervisor = Supervisor(tmp_path)
        for word in expected.split():
            supervisor.start("echo", [sys.executable, "-c", f"print({word!r})"]).wait()
        assert (tmp_path / "echo.log").read_text() == expected


def test_a_service_runs_from_its_config_file(tmp_path):
    supervisor = Supervisor(tmp_path)
    config = IngestConfig(robot_id="r", source="replay")  # a replay without a path: the ingest refuses it
    process = supervisor.start_service("ingest", "ingest", config)
    assert process.wait(timeout=120) != 0
    assert tomllib.loads((tmp_path / "ingest.toml").read_text()) == {"robot_id": "r", "source": "replay"}
    assert "needs replay.path" in (tmp_path / "ingest.log").read_text()


def test_the_log_level_comes_from_the_environment_and_a_bad_one_is_named(monkeypatch):
    monkeypatch.delenv(ENV_LOG_LEVEL, raising=False)
    assert log_level_from_environment() == logging.INFO
    monkeypatch.setenv(ENV_LOG_LEVEL, " debug ")
    assert log_level_from_environment() == logging.DEBUG
    monkeypatch.setenv(ENV_LOG_LEVEL, "chatty")
    with pytest.raises(ConfigError, match=r"LOCNERF_LOG_LEVEL='chatty': expected one of DEBUG, INFO, WARNING, ERROR"):
        log_level_from_environment()
