"""A reduced `locnerf eval single-image` / `eval global` run on a tiny fern map trained in the test."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from locnerf.data import read_dataset
from locnerf.field.grid import GridFieldConfig
from locnerf.field.map_file import save_map
from locnerf.train import BuildConfig, build_map
from locnerf_cli.main import main
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
    argv = [
        "eval",
        command,
        "--map",
        str(tiny_fern_map),
        "--data",
        str(shared_data / "llff" / "fern"),
        "--starts",
        str(shared_data / "locnerf_logs" / logs),
        "--trials",
        "1",
        "--updates",
        "2",
        "--seed",
        "0",
        "--device",
        "cpu",
        "--plots",
        str(plots),
        "--json",
    ]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert len(report["trials"]) == 6  # five logged starts and one seeded
    totals = report["totals"]
    assert totals["all"]["trials"] == 6 and 0.0 <= totals["all"]["success_rate"] <= 1.0
    assert totals["logged_starts"]["trials"] == 5
    # The original's own runs on the same starts are scored beside ours.
    assert totals["original_locnerf_on_logged_starts"]["trials"] == 5
    # Per trial: the error history against rays, forward passes and wall time, from the start on.
    first = report["trials"][0]
    history = first["history"]
    assert len(history["rays"]) == len(history["forward_passes"]) == len(history["seconds"]) == len(history["translation_error"]) == 3
    assert history["rays"][0] == history["forward_passes"][0] == 0 and history["seconds"][0] == 0.0
    assert history["rays"][1] == report["particles"] * report["pixels"]  # the first update renders every particle
    assert history["forward_passes"][-1] == first["forward_passes"] and history["translation_error"][-1] == first["translation_error"]
    assert history["seconds"] == sorted(history["seconds"])
    original = first["original_locnerf"]["history"]
    assert len(original["rays"]) == len(original["translation_error"]) > 10
    assert original["rays"][1] * 128 == original["forward_passes"][1]
    protocol = report["protocol"]
    written = [Path(p) for p in report["plots"]]
    expected = {f"{protocol}_{name}.png" for name in ("error_curves", "error_vs_time", "success_vs_rays", "mean_error_vs_rays", "image_vs_render")}
    assert {p.name for p in written} == expected
    assert all(p.is_file() and p.stat().st_size > 1000 for p in written)
