"""Which pixels the likelihood looks at: gradient weights against a naive loop, the draw's shares."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.measurement import gradient_weights, sample_pixels, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig


def naive_gradient_weights(image: torch.Tensor) -> torch.Tensor:
    """Central differences of the grey image (zero on the border), magnitude, 3×3 maximum: pixel by pixel in float64."""
    grey = image.double().mean(dim=-1)
    height, width = grey.shape
    magnitude = torch.zeros(height, width, dtype=torch.float64)
    for v in range(height):
        for u in range(width):
            du = 0.5 * float(grey[v, u + 1] - grey[v, u - 1]) if 0 < u < width - 1 else 0.0
            dv = 0.5 * float(grey[v + 1, u] - grey[v - 1, u]) if 0 < v < height - 1 else 0.0
            magnitude[v, u] = math.hypot(du, dv)
    dilated = torch.zeros_like(magnitude)
    for v in range(height):
        for u in range(width):
            dilated[v, u] = magnitude[max(v - 1, 0) : v + 2, max(u - 1, 0) : u + 2].max()
    return dilated.flatten()


def _two_edges(height: int = 30, width: int = 40) -> torch.Tensor:
    """Grey image: 0 left of column 10, 1 from 10 to 29, 0.8 from column 30 (a strong and a weak edge)."""
    image = torch.zeros(height, width, 3)
    image[:, 10:30] = 1.0
    image[:, 30:] = 0.8
    return image


def test_gradient_weights_match_the_naive_loop(generator):
    image = torch.rand(17, 23, 3, generator=generator)
    assert torch.allclose(gradient_weights(image).double(), naive_gradient_weights(image), atol=1e-6)


def test_gradient_draws_land_on_edges_in_their_share_and_favour_strong_edges(generator):
    config = MeasurementConfig(pixels=200, sampling="gradient", gradient_share=0.75)
    image = _two_edges()
    on_strong = on_weak = 0
    for _ in range(20):
        pixels = sample_pixels_of_image(image, config, generator)
        assert len({tuple(p) for p in pixels.tolist()}) == 200
        assert pixels[:, 0].max() <= 39 and pixels[:, 1].max() <= 29 and pixels.min() >= 0
        u = pixels[:, 0]
        strong, weak = ((u >= 8) & (u <= 11)), ((u >= 28) & (u <= 31))  # the dilated edge bands
        assert int((strong | weak).sum()) >= 150  # the gradient share, plus uniform draws that fall there
        on_strong += int(strong.sum())
        on_weak += int(weak.sum())
    # weights 0.5 against 0.1 per band pixel, 120 pixels per band, 150 draws without replacement per image:
    # the strong band fills up (≈ 110 of 120), the weak one gets the rest (≈ 40): ratio well over 2.
    assert on_strong > 2 * on_weak, (on_strong, on_weak)


def test_flat_image_falls_back_to_uniform_draws(generator):
    config = MeasurementConfig(pixels=64, sampling="gradient")
    pixels = sample_pixels_of_image(torch.full((30, 40, 3), 0.5), config, generator)
    assert len({tuple(p) for p in pixels.tolist()}) == 64


def test_uniform_sampling_is_the_original_draw():
    image = _two_edges()
    config = MeasurementConfig(pixels=64, sampling="uniform")
    drawn = sample_pixels_of_image(image, config, torch.Generator().manual_seed(5))
    assert torch.equal(drawn, sample_pixels(30, 40, 64, torch.Generator().manual_seed(5)))


def test_more_pixels_than_the_image_has_is_refused(generator):
    with pytest.raises(ValueError, match="M=1201"):
        sample_pixels_of_image(_two_edges(), MeasurementConfig(pixels=1201), generator)


def test_the_ray_budget_trades_pixels_for_particles():
    plain = MeasurementConfig(pixels=128)
    assert [plain.pixels_for(n) for n in (1, 300, 2400, 100000)] == [128] * 4
    budget = MeasurementConfig(pixels=128, ray_budget=76800, min_pixels=16)
    assert budget.pixels_for(300) == 128  # 256 fit, the full M is the most
    assert budget.pixels_for(1200) == 64
    assert budget.pixels_for(2400) == 32
    assert budget.pixels_for(1000) == 76
    assert budget.pixels_for(100000) == 16  # never fewer than min_pixels
    with pytest.raises(ValueError, match="particles=0"):
        budget.pixels_for(0)


def test_an_explicit_count_overrides_the_configured_pixels(generator):
    config = MeasurementConfig(pixels=64, sampling="gradient")
    pixels = sample_pixels_of_image(_two_edges(), config, generator, count=20)
    assert pixels.shape == (20, 2)
    assert len({(float(u), float(v)) for u, v in pixels}) == 20
