"""``locnerf view`` and ``locnerf up --view`` refuse what cannot work with one clear line (exit code 2),
before opening a bus or starting a process."""

from __future__ import annotations

import importlib.util

import pytest

from locnerf_cli.main import main

pytest.importorskip("rerun", reason="the view extra: pip install 'locnerf[view]'")


def test_without_the_extra_the_view_names_the_install_command(monkeypatch, caplog, tmp_path):
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else find_spec(name, *a))
    assert main(["view", "--save", str(tmp_path / "run.rrd")]) == 2
    assert "pip install 'locnerf[view]'" in caplog.records[-1].getMessage()
    assert not (tmp_path / "run.rrd").exists()


def test_without_a_display_the_viewer_is_not_spawned_and_saving_is_suggested(monkeypatch, caplog):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    assert main(["view", "--duration", "1"]) == 2
    assert "no display" in caplog.records[-1].getMessage() and "--save run.rrd" in caplog.records[-1].getMessage()


def test_up_refuses_save_without_view(caplog, tmp_path):
    assert main(["up", "--save", str(tmp_path / "run.rrd"), "--logs", str(tmp_path)]) == 2
    assert "expected --view too" in caplog.records[-1].getMessage()


@pytest.mark.parametrize("command", [["view"], ["up", "--view", "--port", "0"]])
def test_a_recording_in_a_missing_folder_is_refused_before_anything_starts(command, caplog, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # up's default logs folder would be created here
    save = tmp_path / "missing" / "run.rrd"
    assert main([*command, "--save", str(save)]) == 2
    assert f"--save {save}: expected a file in an existing folder" in caplog.records[-1].getMessage()
    assert sorted(tmp_path.iterdir()) == []  # no logs, no recording
