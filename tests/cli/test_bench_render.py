"""``locnerf bench render`` on a tiny grid map: the JSON figures and the refusal of bad thread counts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.field.grid_map import GridMap
from locnerf.field.map_file import save_map
from locnerf.field.map_info import MapInfo
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics
from locnerf_cli.main import main


@pytest.fixture
def restore_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def test_bench_render_prints_rates(tmp_path: Path, generator: torch.Generator, capsys, caplog, restore_threads) -> None:
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = GridField(box, GridFieldConfig(voxels=10**3, features=2), background=(1.0, 1.0, 1.0))
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator) * 3.0)
    field.update_occupancy()
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    poses[:, 2, 3] = torch.tensor([3.0, 3.5])
    intrinsics = PinholeIntrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    path = save_map(GridMap(field.eval(), MapInfo(MapNormalization(), intrinsics, poses, {})), tmp_path / "tiny.locmap")
    arguments = ["bench", "render", "--map", str(path), "--particles", "4", "--pixels", "8", "--repeats", "2", "--device", "cpu"]
    assert main([*arguments, "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["rays"] == 32 and figures["threads"] == 1
    assert figures["update_hz"] > 0 and figures["speedup_vs_mlp"] > 0
    assert main([*arguments, "--threads", "0"]) == 2
    assert "--threads 0: expected at least 1" in caplog.text
