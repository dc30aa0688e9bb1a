"""A search's likelihood: the update's own, or the search's own colour pixels with the update's depth term kept."""

from __future__ import annotations

import math

import torch

from locnerf.filter.measurement import observed_colours, particle_log_likelihoods, sample_pixels
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.update_likelihood import UpdateLikelihood, search_likelihood, with_depth
from locnerf.geometry import make_pose, se3_exp, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from tests.filter.analytic_field import analytic_render_rays

CAMERA = PinholeIntrinsics.from_fov(40, 30, math.radians(60))
TRUTH = make_pose(so3_exp(torch.tensor([0.1, 0.3, -0.05], dtype=torch.float64)), torch.tensor([0.2, -0.1, 0.4], dtype=torch.float64))


def _depth_term(poses: torch.Tensor) -> torch.Tensor:
    """A stand-in depth term that differs per pose: ten times the x coordinate."""
    return 10.0 * poses[:, 0, 3]


def test_a_search_without_own_pixels_scores_the_updates_likelihood():
    likelihood = UpdateLikelihood(_depth_term, 7, 0, False)
    score, rays = search_likelihood(likelihood, None, None, MeasurementConfig(), CAMERA, analytic_render_rays, torch.device("cpu"))
    assert score is _depth_term and rays == 7


def test_a_search_with_own_pixels_renders_them_and_keeps_the_depth_term(generator):
    """The float64 oracle: the measurement model on the search's pixels plus the update's depth term, per pose; the
    rays per pose are the search's pixels and the depth term's; without a depth term the colour alone."""
    image = render_image(analytic_render_rays, TRUTH.float(), CAMERA)
    pixels = sample_pixels(CAMERA.height, CAMERA.width, 200, generator)
    observed = observed_colours(image, pixels)
    poses = torch.stack([TRUTH @ se3_exp(torch.tensor([0.0, 0.01 * k, 0.0, 0.02 * k, 0.0, 0.0], dtype=torch.float64)) for k in range(4)])
    colour = particle_log_likelihoods(poses, pixels, observed, CAMERA, analytic_render_rays)
    for depth_term, depth_rays in ((_depth_term, 30), (None, 0)):
        likelihood = UpdateLikelihood(
            with_depth(lambda p: torch.zeros(len(p), dtype=torch.float64), depth_term), 64 + depth_rays, 0, False, depth_term, depth_rays
        )
        score, rays = search_likelihood(likelihood, pixels, observed, MeasurementConfig(), CAMERA, analytic_render_rays, torch.device("cpu"))
        expected = colour + (_depth_term(poses) if depth_term is not None else 0.0)
        torch.testing.assert_close(score(poses), expected)
        assert rays == 200 + depth_rays
    assert int(colour.argmax()) == 0  # the truth's pixels prefer the truth
