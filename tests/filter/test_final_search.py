"""The final local search (locnerf.filter.final_search) on an analytic object seen from outside.

The scene is a textured ball of radius 1 at the origin on a white background, seen from 4 units
away by a narrow camera: swinging the camera about the ball's centre (a sideways shift with the
turn that keeps the ball in view) leaves the silhouette where it is and moves only the texture,
the valley the lego trials end in. From 7 cm along it and a converged cloud's narrow covariance the
search must close more than half of the way with the pivot swings and not move without them, and its reported likelihood
must match a float64 evaluation of eq. 5 at the returned pose.
"""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.final_search import FinalSearchConfig, final_search
from locnerf.filter.measurement import observed_colours, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.motion import PivotNoise
from locnerf.geometry import make_pose, rotation_error_deg, se3_exp, translation_error
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from locnerf.render.rays import rays_from_poses_and_pixels

CAMERA = PinholeIntrinsics.centred(fx=140.0, fy=140.0, width=64, height=64)
EDGE = 0.01  # width of the silhouette's soft edge (map units)


def ball(origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """origins (R, 3), directions (R, 3) -> rgb (R, 3): a textured unit ball at the origin on white."""
    unit = directions / directions.norm(dim=-1, keepdim=True)
    closest = origins - (origins * unit).sum(dim=-1, keepdim=True) * unit  # point of the ray nearest the centre
    alpha = torch.sigmoid((1.0 - closest.norm(dim=-1, keepdim=True)) / EDGE)
    frequencies = 3.0 * torch.tensor([[3.1, 1.7, 2.3], [1.9, 2.7, 0.5], [2.3, 0.9, 3.4]], dtype=origins.dtype)
    texture = 0.5 + 0.4 * torch.sin(closest @ frequencies.T + torch.tensor([0.0, 1.0, 2.0], dtype=origins.dtype))
    return alpha * texture + (1.0 - alpha)


TRUTH = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64))
CONVERGED = torch.diag(torch.tensor([math.radians(0.02)] * 3 + [0.001] * 3, dtype=torch.float64) ** 2)
"""A converged cloud's covariance: much narrower than the start's offset."""


def swung(angle_deg: float) -> torch.Tensor:
    """The truth swung by ``angle_deg`` about its x axis through the ball's centre, 4 units ahead: along the valley."""
    pivot = PivotNoise(4.0, torch.zeros(2, dtype=torch.float64)).tangent_map()
    return TRUTH @ se3_exp(pivot @ torch.tensor([math.radians(angle_deg), 0.0], dtype=torch.float64))


@pytest.mark.parametrize(("pivot_depth", "within"), [(4.0, True), (None, False)])
def test_search_follows_the_valley_with_the_pivot_swings(pivot_depth: float | None, within: bool) -> None:
    image = render_image(ball, TRUTH.float(), CAMERA)
    start = swung(1.0)
    config = FinalSearchConfig(pixels=512, iterations=6, candidates=48, elite=8, pivot_depth=pivot_depth, pivot_sigma_deg=1.0)
    result = final_search(start, CONVERGED, image, CAMERA, ball, MeasurementConfig(), config, torch.Generator().manual_seed(0))
    assert float(translation_error(start, TRUTH)) == pytest.approx(4.0 * math.radians(1.0), rel=1e-3)  # 7 cm along the valley
    assert result.log_likelihood >= result.start_log_likelihood
    assert result.rays == 512 * (1 + 6 * 48)
    if within:  # more than half of the 7 cm closed (measured: 2.6 cm left)
        assert float(translation_error(result.pose, TRUTH)) < 0.035
        assert float(rotation_error_deg(result.pose, TRUTH)) < 0.5
    else:  # the cloud's own spread does not reach along the valley
        assert float(translation_error(result.pose, TRUTH)) > 0.06


def test_reported_likelihood_is_eq5_at_the_returned_pose_in_float64() -> None:
    image = render_image(ball, TRUTH.float(), CAMERA)
    mean, covariance = swung(0.5), CONVERGED
    measurement = MeasurementConfig(exponent=4.0)
    config = FinalSearchConfig(pixels=256, iterations=2, candidates=16, elite=4)
    result = final_search(mean, covariance, image, CAMERA, ball, measurement, config, torch.Generator().manual_seed(5))
    pixels = sample_pixels_of_image(image, measurement, torch.Generator().manual_seed(5), 256)  # the search's first draw
    origins, directions = rays_from_poses_and_pixels(result.pose[None].float().double(), pixels, CAMERA)
    residual = ball(origins[0], directions[0]) - observed_colours(image, pixels).double()
    expected = 4.0 * (math.log(256) - math.log(float((residual * residual).sum())))
    assert result.log_likelihood == pytest.approx(expected, abs=1e-3)


def test_bad_settings_and_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="elite=9 > candidates=8"):
        FinalSearchConfig(candidates=8, elite=9)
    image = render_image(ball, TRUTH.float(), CAMERA)
    with pytest.raises(ValueError, match=r"\(6, 6\) covariance"):
        final_search(TRUTH, torch.eye(3), image, CAMERA, ball, MeasurementConfig(), FinalSearchConfig(), torch.Generator())
