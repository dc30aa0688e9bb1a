"""Measurement model (eq. 5): float64 naive oracle, best particle at the truth, bad input."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.initialization import gaussian_particles
from locnerf.filter.measurement import (
    log_likelihood_from_errors,
    observed_colours,
    particle_log_likelihoods,
    sample_pixels,
)
from locnerf.geometry import make_pose, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from tests.filter.analytic_field import analytic_render_rays

CAMERA = PinholeIntrinsics.from_fov(40, 30, math.radians(60))


def naive_log_likelihood(pose: torch.Tensor, pixels: torch.Tensor, observed: torch.Tensor, exponent: float) -> float:
    """One particle, one pixel at a time, in float64."""
    total = 0.0
    for (u, v), colour in zip(pixels.tolist(), observed.double()):
        direction = pose[:3, :3] @ torch.tensor([(u - CAMERA.cx) / CAMERA.fx, -(v - CAMERA.cy) / CAMERA.fy, -1.0], dtype=torch.float64)
        rendered = analytic_render_rays(pose[None, :3, 3], direction[None])[0]
        total += float(((rendered - colour) ** 2).sum())
    return exponent * (math.log(len(pixels)) - math.log(total))


def test_vectorised_likelihood_matches_naive_float64_loop(generator):
    truth = make_pose(so3_exp(torch.tensor([0.1, 0.2, 0.0], dtype=torch.float64)), torch.tensor([0.3, 0.0, 1.0], dtype=torch.float64))
    image = render_image(analytic_render_rays, truth, CAMERA)
    poses = gaussian_particles(truth, torch.eye(6, dtype=torch.float64) * 0.01, 12, generator)
    pixels = sample_pixels(CAMERA.height, CAMERA.width, 16, generator).double()
    observed = observed_colours(image, pixels)
    fast = particle_log_likelihoods(poses, pixels, observed, CAMERA, analytic_render_rays, exponent=4.0, ray_chunk=37)
    slow = torch.tensor([naive_log_likelihood(p, pixels, observed, 4.0) for p in poses], dtype=torch.float64)
    assert torch.allclose(fast, slow, rtol=1e-9)


def test_true_pose_gets_the_highest_likelihood(generator):
    truth = torch.eye(4, dtype=torch.float64)
    image = render_image(analytic_render_rays, truth, CAMERA)
    poses = torch.cat([truth[None], gaussian_particles(truth, torch.eye(6, dtype=torch.float64) * 0.02, 30, generator)])
    pixels = sample_pixels(CAMERA.height, CAMERA.width, 64, generator)
    scores = particle_log_likelihoods(poses, pixels, observed_colours(image, pixels), CAMERA, analytic_render_rays)
    assert int(scores.argmax()) == 0


def test_float32_and_float64_agree(generator):
    truth = torch.eye(4, dtype=torch.float64)
    image = render_image(analytic_render_rays, truth, CAMERA)
    poses = gaussian_particles(truth, torch.eye(6, dtype=torch.float64) * 0.05, 20, generator)
    pixels = sample_pixels(CAMERA.height, CAMERA.width, 64, generator)
    observed = observed_colours(image, pixels)
    high = particle_log_likelihoods(poses, pixels, observed, CAMERA, analytic_render_rays)
    low = particle_log_likelihoods(poses.float(), pixels, observed.float(), CAMERA, analytic_render_rays)
    assert torch.allclose(high, low, atol=1e-3)


def test_sampled_pixels_are_distinct_and_inside(generator):
    pixels = sample_pixels(30, 40, 1200, generator)
    assert len({tuple(p) for p in pixels.tolist()}) == 1200
    assert pixels[:, 0].max() <= 39 and pixels[:, 1].max() <= 29 and pixels.min() >= 0


def test_too_many_pixels_is_refused(generator):
    with pytest.raises(ValueError, match="M=1201"):
        sample_pixels(30, 40, 1201, generator)


def test_nan_render_gives_zero_likelihood():
    scores = log_likelihood_from_errors(torch.tensor([float("nan"), 1.0]), 64, 4.0)
    assert scores[0] == -math.inf and math.isfinite(scores[1])
