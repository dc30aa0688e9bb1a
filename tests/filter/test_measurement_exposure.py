"""Exposure-invariant likelihood: closed-form gain and bias against a naive float64 loop, invariance, bad input."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.initialization import gaussian_particles
from locnerf.filter.measurement import exposure_compensated_residuals, observed_colours, particle_log_likelihoods, sample_pixels
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.geometry import make_pose, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from tests.filter.analytic_field import analytic_render_rays

CAMERA = PinholeIntrinsics.from_fov(40, 30, math.radians(60))


def naive_residuals(rendered: torch.Tensor, observed: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """One particle and channel at a time: the gain minimising the SSE over a fine grid of gains, then the best bias."""
    out = torch.empty_like(rendered, dtype=torch.float64)
    for n in range(rendered.shape[0]):
        for c in range(3):
            r, o = rendered[n, :, c].double(), observed[:, c].double()
            best = None
            for g in torch.linspace(low, high, 20001, dtype=torch.float64):
                b = (o - g * r).mean()
                sse = float(((o - g * r - b) ** 2).sum())
                if best is None or sse < best[0]:
                    best = (sse, g, b)
            _, g, b = best
            out[n, :, c] = o - g * r - b
    return out


def test_closed_form_matches_a_naive_search_over_gains(generator: torch.Generator) -> None:
    rendered = torch.rand(4, 10, 3, generator=generator, dtype=torch.float64)
    observed = 1.4 * rendered[0] + 0.05 * torch.randn(10, 3, generator=generator, dtype=torch.float64) - 0.1
    rendered[2] = 0.3  # a flat render: no gain can be fitted, it keeps g = 1
    rendered[3] = 1.0 - rendered[0]  # anti-correlated: the gain is clamped to the low bound
    fast = exposure_compensated_residuals(rendered, observed, (0.5, 2.0))
    # The search's gain grid spacing is 7.5e-5, so residuals agree to about that times a colour.
    torch.testing.assert_close(fast, naive_residuals(rendered, observed, 0.5, 2.0), atol=2e-4, rtol=0)


def test_a_change_of_exposure_shifts_every_log_likelihood_by_one_constant(generator: torch.Generator) -> None:
    truth = make_pose(so3_exp(torch.tensor([0.1, 0.2, 0.0], dtype=torch.float64)), torch.tensor([0.3, 0.0, 1.0], dtype=torch.float64))
    image = render_image(analytic_render_rays, truth, CAMERA)
    poses = gaussian_particles(truth, torch.eye(6, dtype=torch.float64) * 0.01, 8, generator)
    pixels = sample_pixels(CAMERA.height, CAMERA.width, 32, generator).double()
    observed = observed_colours(image, pixels)
    darker = observed * 0.75 + torch.tensor([0.02, 0.0, 0.01], dtype=torch.float64)
    plain = particle_log_likelihoods(poses, pixels, observed, CAMERA, analytic_render_rays, exposure_gain_range=(0.1, 10.0))
    shifted = particle_log_likelihoods(poses, pixels, darker, CAMERA, analytic_render_rays, exposure_gain_range=(0.1, 10.0))
    # A wide gain range, so that no fitted gain is clamped: every fitted gain scales by 0.75 (the biases
    # absorb the offsets), so every residual does, and the log-likelihoods shift by one constant,
    # 2γ·log(1/0.75): the ranking of the particles is kept.
    torch.testing.assert_close(shifted - plain, (shifted - plain)[:1].expand(8), atol=1e-6, rtol=0)
    uncompensated = particle_log_likelihoods(poses, pixels, darker, CAMERA, analytic_render_rays)
    assert not torch.allclose(uncompensated - plain, (uncompensated - plain)[:1].expand(8), atol=1e-3)


@pytest.mark.parametrize("bounds", [(0.0, 2.0), (1.2, 2.0), (0.5, 0.9), (-1.0, 1.0)])
def test_gain_ranges_that_exclude_the_identity_are_refused(bounds: tuple[float, float]) -> None:
    with pytest.raises(ValueError, match="exposure_gain_range"):
        MeasurementConfig(exposure_gain_range=bounds)
