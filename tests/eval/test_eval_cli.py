"""A reduced `locnerf eval single-image` / `eval global` run on a tiny fern map trained in the test."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from locnerf.cli.main import main
from locnerf.data import read_dataset
from locnerf.field.grid import GridFieldConfig
from locnerf.field.map_file import save_map
from locnerf.train import BuildConfig, build_map
from tests.conftest import SHARED_DATA


@pytest.fixture(scope="module")
def tiny_fern_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    train = read_dataset(SHARED_DATA / "llff" / "fern", split="train", downscale=8)
    config = BuildConfig(steps=40, batch_rays=1024, field=GridFieldConfig(voxels=32**3), seed=0)
    return save_map(build_map(train, config), tmp_path_factory.mktemp("maps") / "tiny_fern.locmap")


@pytest.mark.parametrize(("command", "logs"), [("single-image", "inerf_compare"), ("global", "global_loc")])
def test_reduced_experiment_reports_ours_beside_the_logs_and_writes_figures(
    command: str, logs: str, tiny_fern_map: Path, shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plots = tmp_path / "plots"
    argv = ["eval", command, "--map", str(tiny_fern_map), "--data", str(shared_data / "llff" / "fern"),
            "--starts", str(shared_data / "locnerf_logs" / logs), "--trials", "1", "--updates", "2", "--seed", "0",
            "--device", "cpu", "--plots", str(plots), "--json"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert len(report["trials"]) == 6  # five logged starts and one seeded
    totals = report["totals"]
    assert totals["all"]["trials"] == 6 and 0.0 <= totals["all"]["success_rate"] <= 1.0
    assert totals["logged_starts"]["trials"] == 5
    # The original's own runs on the same starts are scored beside ours.
    assert totals["original_locnerf_on_logged_starts"]["trials"] == 5
    written = [Path(p) for p in report["plots"]]
    assert {p.name for p in written} >= {f"{report['protocol']}_error_curves.png", f"{report['protocol']}_image_vs_render.png"}
    assert all(p.is_file() and p.stat().st_size > 1000 for p in written)
