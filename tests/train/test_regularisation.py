"""Per-image exposure and grid total variation: hand-worked values, a learned gain, and a short RGB-D build using both."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from locnerf.data import read_dataset
from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.train import BuildConfig, RoomConfig, build_map
from locnerf.train.build import config_for
from locnerf.train.exposure import ImageExposure
from locnerf.train.total_variation import grid_total_variation

BOX = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])


def test_exposure_starts_as_the_identity_and_learns_a_gain_and_bias() -> None:
    generator = torch.Generator().manual_seed(3)
    exposure = ImageExposure(2)
    colours = torch.rand(256, 3, generator=generator)
    image_index = torch.randint(0, 2, (256,), generator=generator)
    torch.testing.assert_close(exposure(colours, image_index), colours)
    # Image 1 was taken 1.5× brighter than image 0 with a 0.1 offset in red: about the average exposure,
    # image 0 is 0.8× and image 1 1.2× as bright, with red offsets -0.05 and +0.05.
    gain = torch.tensor([[0.8, 0.8, 0.8], [1.2, 1.2, 1.2]])
    bias = torch.tensor([[-0.05, 0.0, 0.0], [0.05, 0.0, 0.0]])
    target = colours * gain[image_index] + bias[image_index]
    optimizer = torch.optim.Adam(exposure.parameters(), lr=0.02)
    for _ in range(500):
        optimizer.zero_grad()
        torch.mean((exposure(colours, image_index) - target) ** 2).backward()
        optimizer.step()
    learned_gain, learned_bias = exposure.transforms()
    torch.testing.assert_close(learned_gain.detach(), gain, atol=0.01, rtol=0)
    torch.testing.assert_close(learned_bias.detach(), bias, atol=0.01, rtol=0)


def test_exposure_is_anchored_to_the_average_image() -> None:
    """A change common to every image is the field's to learn, not the transforms': they keep mean gain 1 and mean bias 0."""
    exposure = ImageExposure(3)
    with torch.no_grad():
        exposure.gain.mul_(torch.tensor([[1.3], [1.3], [1.3]]))
        exposure.bias.add_(0.2)
    colours = torch.rand(8, 3, generator=torch.Generator().manual_seed(4))
    torch.testing.assert_close(exposure(colours, torch.arange(8) % 3), colours)


def test_exposure_refuses_an_empty_image_set() -> None:
    with pytest.raises(ValueError, match="images=0"):
        ImageExposure(0)


def test_total_variation_of_a_ramp_along_x() -> None:
    field = GridField(BOX, GridFieldConfig(voxels=4**3, features=0), background=None)  # 4³ cells: 5 × 5 × 5 vertices, 4 channels
    x = torch.arange(5 * 5 * 5) % 5
    with torch.no_grad():
        field.grid.copy_(0.5 * x[:, None].float().expand(-1, 4))
    assert float(grid_total_variation(GridField(BOX, GridFieldConfig(voxels=4**3, features=0), None), 64, torch.Generator().manual_seed(0)).detach()) == 0.0
    vertices = 4000
    tv = grid_total_variation(field, vertices, torch.Generator().manual_seed(0))
    # The same draw: each vertex off the last x layer differs by 0.5 in all 4 channels from its +x
    # neighbour and by nothing along y and z, so the mean over 3 axes and 4 channels is 0.25 · share / 3.
    drawn = torch.randint(0, 125, (vertices,), generator=torch.Generator().manual_seed(0))
    share = float((drawn % 5 < 4).float().mean())
    torch.testing.assert_close(tv, torch.tensor(0.25 * share / 3))
    tv.backward()
    assert field.grid.grad is not None and float(field.grid.grad.abs().sum()) > 0


def test_total_variation_refuses_zero_vertices() -> None:
    field = GridField(BOX, GridFieldConfig(voxels=4**3), background=None)
    with pytest.raises(ValueError, match="vertices=0"):
        grid_total_variation(field, 0, torch.Generator().manual_seed(0))


def test_defaults_keep_both_off() -> None:
    config = BuildConfig()
    assert config.exposure_learning_rate is None and config.tv_weight == 0.0


def test_short_rgbd_build_with_exposure_and_total_variation(shared_data: Path) -> None:
    """Ten kitchen frames at 40x30: the build runs with both, and the saved map holds the field only."""
    frames = read_dataset(shared_data / "7scenes_redkitchen", split="train", downscale=16, stride=60)
    config = BuildConfig(
        steps=30,
        batch_rays=512,
        depth_batch_rays=512,
        field=GridFieldConfig(voxels=24**3),
        occupancy_warmup=10,
        seed=2,
        exposure_learning_rate=1e-3,
        tv_weight=1e-3,
        tv_vertices=1000,
    )
    radiance_map = build_map(frames, config)
    assert radiance_map.metadata["steps"] == 30
    assert {name.split(".")[0] for name, _ in radiance_map.field.named_parameters()} == {"grid", "decoder"}
    assert torch.isfinite(radiance_map.field.grid).all()


def test_room_settings_replace_the_defaults_for_rgbd_data_only_and_explicit_settings_win(shared_data: Path) -> None:
    frames = read_dataset(shared_data / "7scenes_redkitchen", split="train", downscale=16, stride=120)
    room = config_for(frames, BuildConfig())
    expected = RoomConfig()
    assert (room.field.voxels, room.field.features) == (expected.voxels, expected.features)
    assert (room.tv_weight, room.depth_weight, room.free_space_weight) == (expected.tv_weight, expected.depth_weight, expected.free_space_weight)
    explicit = config_for(frames, BuildConfig(field=GridFieldConfig(voxels=1000, features=8), tv_weight=0.0, depth_weight=0.1, free_space_weight=0.0))
    assert (explicit.field.voxels, explicit.field.features) == (1000, 8)
    assert (explicit.tv_weight, explicit.depth_weight, explicit.free_space_weight) == (0.0, 0.1, 0.0)
    colour_only = config_for(frames.without_depth(), BuildConfig())
    assert colour_only.field == GridFieldConfig() and (colour_only.tv_weight, colour_only.free_space_weight) == (0.0, 0.0)
