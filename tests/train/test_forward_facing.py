"""Forward-facing builds: NDC-shaped voxels (coarse depth), per-axis steps, and the settings they replace."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from locnerf.data import read_llff, read_nerf_synthetic
from locnerf.field.grid import GridField, GridFieldConfig, grid_shape_for_box
from locnerf.train import BuildConfig
from locnerf.train.build import config_for


def test_grid_shape_follows_the_voxel_aspect() -> None:
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert grid_shape_for_box(box, 64**3) == grid_shape_for_box(box, 64**3, (1.0, 1.0, 1.0)) == (65, 65, 65)
    rx, ry, rz = grid_shape_for_box(box, 100_000, (1.0, 2.0, 4.0))
    # edges 2/(R-1) in the ratio 1:2:4
    assert (rx - 1) == pytest.approx(2 * (ry - 1), abs=2) and (rx - 1) == pytest.approx(4 * (rz - 1), abs=4)
    assert 100_000 <= rx * ry * rz < 120_000  # ceil(extent / edge) + 1 vertices per axis rounds up
    with pytest.raises(ValueError, match="voxel aspect"):
        grid_shape_for_box(box, 1000, (1.0, 0.0, 1.0))


def _uniform_fog(sigma_per_voxel: float) -> GridField:
    """Anisotropic field (z voxels 4× longer) of constant density and white colour, no view term."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = GridField(box, GridFieldConfig(voxels=40 * 40 * 10, features=0, voxel_aspect=(1.0, 1.0, 4.0)), background=None).double()
    with torch.no_grad():
        field.grid[:, 0] = math.log(math.expm1(sigma_per_voxel)) - field.density_shift
        field.grid[:, 1:4] = 30.0  # sigmoid -> 1: the colour equals the opacity
    return field


def test_steps_and_optical_depth_are_per_axis_voxel_units() -> None:
    sigma = 0.01
    field = _uniform_fog(sigma)
    rx, ry, rz = field.resolution
    assert rz < rx / 3
    edges = field.voxel_sizes
    torch.testing.assert_close(edges, torch.tensor([2.0 / (rx - 1), 2.0 / (ry - 1), 2.0 / (rz - 1)], dtype=torch.float64))
    origins = torch.tensor([[0.1, 0.2, -3.0], [-3.0, 0.05, 0.3]], dtype=torch.float64)
    directions = torch.tensor([[0.0, 0.0, 0.5], [2.0, 0.0, 0.0]], dtype=torch.float64)
    # one voxel along z is edges[2] long: ray parameter edges[2] / 0.5; along x edges[0] / 2
    torch.testing.assert_close(field.ray_parameter_per_voxel(directions), torch.stack((edges[2] / 0.5, edges[0] / 2.0)))
    # crossing the box: rz - 1 voxels along z, rx - 1 along x; opacity 1 - exp(-σ · voxels crossed)
    expected = 1.0 - torch.exp(-sigma * torch.tensor([rz - 1.0, rx - 1.0], dtype=torch.float64))
    with torch.no_grad():
        trained = field.render_training(origins, directions, directions, generator=None)
    rendered = field.render(origins, directions, directions)
    torch.testing.assert_close(trained[:, 0], expected, atol=1e-6, rtol=0)
    torch.testing.assert_close(rendered[:, 0], expected, atol=1e-6, rtol=0)


def test_forward_facing_settings_replace_the_general_ones_for_ndc_data_only(shared_data: Path) -> None:
    config = BuildConfig()
    fern = config_for(read_llff(shared_data / "llff" / "fern", downscale=8, split="test"), config)
    ndc = config.forward_facing
    assert fern.field.voxel_aspect == (1.0, 504 / 378, ndc.depth_ratio)
    assert (fern.field.step_ratio, fern.field.initial_alpha, fern.field.render_step_factor) == (ndc.step_ratio, ndc.initial_alpha, ndc.render_step_factor)
    assert (fern.batch_rays, fern.grid_learning_rate, fern.occupancy_warmup) == (ndc.batch_rays, ndc.grid_learning_rate, ndc.occupancy_warmup)
    lego = read_nerf_synthetic(shared_data / "nerf_synthetic" / "lego", split="val", downscale=16, skip_missing=True)
    assert config_for(lego, config) is config


def test_the_ndc_grid_box_covers_every_training_ray_and_object_boxes_stay(shared_data: Path) -> None:
    from locnerf.field.map_info import MapInfo
    from locnerf.train.build import field_box, training_rays

    fern = read_llff(shared_data / "llff" / "fern", downscale=8, split="test")
    info = MapInfo(fern.normalization, fern.intrinsics, fern.T_world_cam.double(), {})
    field_origins, field_directions = info.field_rays(*training_rays(fern, torch.device("cpu"))[:2])
    box = field_box(fern, field_origins, field_directions)
    ends = torch.cat((field_origins, field_origins + field_directions)).double()
    # float32 rays: their NDC depth ends are ±1 to within rounding
    assert (ends >= box[0] - 1e-6).all() and (ends <= box[1] + 1e-6).all()
    # fern's side cameras see past NDC's [-1, 1]² (the reference frustum); depth stays [-1, 1]
    assert box[0, 0] < -1.1 and box[1, 0] > 1.1
    torch.testing.assert_close(box[:, 2], torch.tensor([-1.0, 1.0], dtype=torch.float64))
    lego = read_nerf_synthetic(shared_data / "nerf_synthetic" / "lego", downscale=16, split="val", skip_missing=True)
    unchanged = field_box(lego, torch.zeros(1, 3), torch.full((1, 3), 100.0))
    torch.testing.assert_close(unchanged, lego.scene_bounds.double())
