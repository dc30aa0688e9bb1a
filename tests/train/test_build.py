"""A tiny grid map trained inside the test run, evaluated, saved and reloaded."""

from __future__ import annotations

from pathlib import Path

import torch

from locnerf.data import read_nerf_synthetic
from locnerf.field.grid import GridFieldConfig
from locnerf.field.map_file import load_map, save_map
from locnerf.train import BuildConfig, build_map, evaluate_map
from locnerf.train.metrics import psnr, ssim


def test_metrics_hand_worked() -> None:
    image = torch.zeros(16, 16, 3)
    assert abs(psnr(image + 0.1, image) - 20.0) < 1e-5  # 0.1 is not exact in float32
    assert abs(ssim(image + 0.3, image + 0.3) - 1.0) < 1e-9
    assert ssim(torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0)), image + 0.5) < 0.1


def test_tiny_lego_map_learns_and_survives_the_map_file(shared_data: Path, tmp_path: Path) -> None:
    lego = shared_data / "nerf_synthetic" / "lego"
    train = read_nerf_synthetic(lego, split="train", downscale=16).subset(list(range(0, 100, 2)))
    views = read_nerf_synthetic(lego, split="val", downscale=16, skip_missing=True)
    config = BuildConfig(steps=250, batch_rays=1024, field=GridFieldConfig(voxels=40**3), occupancy_warmup=60, final_occupancy_alpha=1e-3, seed=3)
    radiance_map = build_map(train, config)
    assert radiance_map.metadata["steps"] == 250
    scores = evaluate_map(radiance_map.render_rays, views)
    # An all-white render of these views scores about 13 dB; this 40³ map after 250 steps reached
    # 17.5 dB when written (seeded); 16 dB leaves room for thread-order rounding.
    white = sum(psnr(torch.ones_like(image), image) for image in views.images) / len(views)
    assert white < 14.0
    assert scores["psnr"] > 16.0, scores
    loaded = load_map(save_map(radiance_map, tmp_path / "tiny.locmap"))
    assert evaluate_map(loaded.render_rays, views)["psnr"] == scores["psnr"]


def test_a_single_threaded_build_of_fixed_steps_is_bit_reproducible(shared_data: Path) -> None:
    lego = shared_data / "nerf_synthetic" / "lego"
    train = read_nerf_synthetic(lego, split="train", downscale=16).subset(list(range(0, 100, 10)))
    config = BuildConfig(steps=40, batch_rays=512, field=GridFieldConfig(voxels=24**3), occupancy_warmup=10, occupancy_every=10, seed=5, threads=1)
    threads = torch.get_num_threads()
    first, second = (build_map(train, config).field.state_dict() for _ in range(2))
    assert torch.get_num_threads() == threads
    assert first.keys() == second.keys() and all(torch.equal(first[name], second[name]) for name in first)
    other_seed = build_map(train, config.model_copy(update={"seed": 6})).field.state_dict()
    assert not torch.equal(first["grid"], other_seed["grid"])
