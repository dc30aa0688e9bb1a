"""The nerf-pytorch compatibility backend: the original's state-dict layout, checkpoint loading, sampling."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from locnerf.field.map_file import load_map, save_map
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import NerfMLP, load_nerf_pytorch_checkpoint, sample_pdf
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics

# nerf-pytorch's NeRF(D=8, W=256, input_ch=63, input_ch_views=27, skips=[4], use_viewdirs=True).
ORIGINAL_SHAPES = {
    **{f"pts_linears.{i}.weight": (256, 63 if i == 0 else 319 if i == 5 else 256) for i in range(8)},
    **{f"pts_linears.{i}.bias": (256,) for i in range(8)},
    "feature_linear.weight": (256, 256),
    "feature_linear.bias": (256,),
    "views_linears.0.weight": (128, 283),
    "views_linears.0.bias": (128,),
    "rgb_linear.weight": (3, 128),
    "rgb_linear.bias": (3,),
    "alpha_linear.weight": (1, 256),
    "alpha_linear.bias": (1,),
}


def _random_state(generator: torch.Generator) -> dict[str, torch.Tensor]:
    return {key: torch.randn(shape, generator=generator) * 0.1 for key, shape in ORIGINAL_SHAPES.items()}


def _info(ndc: bool) -> MapInfo:
    intrinsics = PinholeIntrinsics(fx=40.0, fy=40.0, cx=20.0, cy=15.0, width=40, height=30)
    poses = torch.eye(4, dtype=torch.float64)[None]
    return MapInfo(MapNormalization(ndc=ndc, near=2.0, far=6.0), intrinsics, poses, {})


def test_module_has_the_original_layout() -> None:
    state = NerfMLP().state_dict()
    assert {k: tuple(v.shape) for k, v in state.items()} == ORIGINAL_SHAPES


@pytest.mark.parametrize("ndc", [False, True])
def test_checkpoint_loads_renders_and_round_trips(generator: torch.Generator, tmp_path: Path, ndc: bool) -> None:
    checkpoint = tmp_path / "200000.tar"
    torch.save(
        {"global_step": 200000, "network_fn_state_dict": _random_state(generator), "network_fine_state_dict": _random_state(generator)},
        checkpoint,
    )
    radiance_map = load_nerf_pytorch_checkpoint(checkpoint, _info(ndc), white_background=True)
    assert radiance_map.samples_per_ray == 128
    origins = torch.zeros(6, 3)
    directions = torch.cat((0.2 * torch.randn(6, 2, generator=generator), -torch.ones(6, 1)), dim=1)
    rgb = radiance_map.render_rays(origins, directions)
    assert rgb.shape == (6, 3) and torch.isfinite(rgb).all() and float(rgb.min()) >= 0.0 and float(rgb.max()) <= 1.0
    loaded = load_map(save_map(radiance_map, tmp_path / "nerf.locmap"))
    torch.testing.assert_close(loaded.render_rays(origins, directions), rgb)


def test_checkpoint_refusals(generator: torch.Generator, tmp_path: Path) -> None:
    missing = tmp_path / "missing.tar"
    torch.save({"network_fn_state_dict": _random_state(generator)}, missing)
    with pytest.raises(ValueError, match="missing network_fine_state_dict"):
        load_nerf_pytorch_checkpoint(missing, _info(False), white_background=False)
    wrong = tmp_path / "wrong.tar"
    state = _random_state(generator)
    state["pts_linears.0.weight"] = torch.zeros(256, 60)
    torch.save({"network_fn_state_dict": state, "network_fine_state_dict": state}, wrong)
    with pytest.raises(ValueError, match="8x256 layout"):
        load_nerf_pytorch_checkpoint(wrong, _info(False), white_background=False)


def test_sample_pdf_matches_naive_inverse_cdf(generator: torch.Generator) -> None:
    bins = torch.sort(torch.rand(4, 9, generator=generator, dtype=torch.float64), dim=-1).values
    weights = torch.rand(4, 8, generator=generator, dtype=torch.float64)
    samples = sample_pdf(bins, weights, 16)
    for ray in range(4):
        w = weights[ray] + 1e-5
        cdf = torch.cat((torch.zeros(1, dtype=torch.float64), torch.cumsum(w / w.sum(), 0)))
        for j, u in enumerate(torch.linspace(0, 1, 16, dtype=torch.float64)):
            k = min(int((cdf <= u).sum()) - 1, 7)
            expected = bins[ray, k] + (u - cdf[k]) / (cdf[k + 1] - cdf[k]) * (bins[ray, k + 1] - bins[ray, k])
            assert abs(float(samples[ray, j]) - float(expected)) < 1e-9
