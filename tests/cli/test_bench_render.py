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


def _tiny_map(tmp_path: Path, generator: torch.Generator) -> Path:
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = GridField(box, GridFieldConfig(voxels=10**3, features=2), background=(1.0, 1.0, 1.0))
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator) * 3.0)
    field.update_occupancy()
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    poses[:, 2, 3] = torch.tensor([3.0, 3.5])
    intrinsics = PinholeIntrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    return save_map(GridMap(field.eval(), MapInfo(MapNormalization(), intrinsics, poses, {})), tmp_path / "tiny.locmap")


def test_bench_render_prints_rates(tmp_path: Path, generator: torch.Generator, capsys, caplog, restore_threads) -> None:
    path = _tiny_map(tmp_path, generator)
    arguments = ["bench", "render", "--map", str(path), "--particles", "4", "--pixels", "8", "--repeats", "2", "--device", "cpu"]
    assert main([*arguments, "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["rays"] == 32 and figures["threads"] == 1
    assert figures["update_hz"] > 0 and figures["speedup_vs_mlp"] > 0
    assert main([*arguments, "--threads", "0"]) == 2
    assert "--threads 0: expected at least 1" in caplog.text


@pytest.mark.parametrize(("marcher", "cloud"), [("fused", "spread"), ("torch", "converged")])
def test_bench_render_profiles_the_update_stages(tmp_path: Path, generator: torch.Generator, capsys, restore_threads, marcher: str, cloud: str) -> None:
    """--profile: CPU time per stage of the update step (rays, ray setup, the marcher's stages, decoder, likelihood,
    the depth rays' surface render), each at most the update's wall time; --depth adds the surface render's rate."""
    path = _tiny_map(tmp_path, generator)
    arguments = ["bench", "render", "--map", str(path), "--particles", "5", "--pixels", "6", "--repeats", "2", "--device", "cpu", "--json"]
    assert main([*arguments, "--profile", "--depth", "--cloud", cloud, "--marcher", marcher, "--compare-marchers"]) == 0
    figures = json.loads(capsys.readouterr().out)
    # the two marchers differ by the samples after termination (transmittance < 1e-3; this map's decoder adds nothing)
    assert figures["fused_vs_torch"]["colour_max"] <= 1.5e-3 and figures["fused_vs_torch"]["opacity_max"] <= 1.001e-3
    assert (figures["cloud"], figures["marcher"], figures["rays"]) == (cloud, marcher, 30)
    assert figures["surface_seconds"] > 0 and figures["colour_and_depth_seconds"] > figures["update_seconds"]
    profile = figures["profile_ms"]
    marcher_stages = {"march: first occupied sample, ray order", "march: skip, gather, shade, composite"}
    if marcher == "torch":
        marcher_stages = {"march: empty-space skip", "march: block samples, occupancy test", "march: gather, shade", "march: composite, terminate"}
    expected = {"update: rays from poses and pixels", "update: likelihood", "update: surface render (depth rays)", "render: ray setup (box, lattice)"}
    assert expected | marcher_stages | {"render: view decoder (MLP per ray)"} <= set(profile)
    wall = profile.pop("update step (wall)")
    assert all(0 <= milliseconds <= wall for milliseconds in profile.values())
