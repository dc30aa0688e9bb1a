"""Exponent per pixel: γ·M/M₀ for an update of M pixels, and recovery comparing likelihoods at one γ."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter import Localizer, LocalizerConfig, SearchRegion
from locnerf.filter.localizer import ConvergenceProtectionConfig
from locnerf.filter.measurement import MeasurementConfig, particle_log_likelihoods, sample_pixels_of_image
from locnerf.filter.recovery import RecoveryConfig
from locnerf.geometry import make_pose, se3_exp
from locnerf.render import PinholeIntrinsics, render_image
from tests.filter.analytic_field import analytic_render_rays

_CAMERA = PinholeIntrinsics.from_fov(40, 30, math.radians(60))


def test_the_exponent_is_proportional_to_the_pixels_only_with_a_reference():
    assert MeasurementConfig(exponent=4.0).exponent_for(32) == 4.0
    config = MeasurementConfig(exponent=4.0, exponent_reference_pixels=64)
    assert [config.exponent_for(m) for m in (16, 32, 64, 128)] == [1.0, 2.0, 4.0, 8.0]
    with pytest.raises(ValueError, match="pixels=0"):
        config.exponent_for(0)
    with pytest.raises(ValueError, match="exponent_reference_pixels"):
        MeasurementConfig(exponent_reference_pixels=0)


def _recovering_localizer(generator: torch.Generator, measurement: MeasurementConfig) -> Localizer:
    config = LocalizerConfig(
        particles=40,
        measurement=measurement,
        convergence_protection=ConvergenceProtectionConfig(count=0),
        recovery=RecoveryConfig(enabled=True, alpha_fast=1.0, tolerance=1.0),
    )
    localizer = Localizer(config, generator, dtype=torch.float64, region=SearchRegion(low=(-1.0, -1.0, -1.0), high=(1.0, 1.0, 1.0)))
    spread = torch.randn(40, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.05
    localizer.initialize(se3_exp(spread))
    return localizer


def test_a_synchronous_update_weighs_with_the_exponent_for_its_pixels(generator):
    """Oracle: the update's log-likelihoods are those of particle_log_likelihoods at γ·M/M₀, so the
    recovery monitor, which rescales them to γ, sees exactly what it sees without a reference."""
    image = render_image(analytic_render_rays, make_pose(torch.eye(3), torch.tensor([0.02, 0.0, 0.0])), _CAMERA)
    plain = _recovering_localizer(torch.Generator().manual_seed(5), MeasurementConfig(pixels=32, exponent=4.0))
    scaled = _recovering_localizer(torch.Generator().manual_seed(5), MeasurementConfig(pixels=32, exponent=4.0, exponent_reference_pixels=128))
    poses = scaled.particles.poses.clone()
    pixels = sample_pixels_of_image(image, scaled.config.measurement, torch.Generator().manual_seed(5), 32)
    plain.update(image, _CAMERA, analytic_render_rays)
    scaled.update(image, _CAMERA, analytic_render_rays)
    assert scaled._recovery.log_fast == pytest.approx(plain._recovery.log_fast, rel=1e-9)
    observed = image[pixels[:, 1].long(), pixels[:, 0].long()].double()
    expected = particle_log_likelihoods(poses, pixels, observed, _CAMERA, analytic_render_rays, exponent=1.0)
    assert scaled._recovery.log_fast == pytest.approx(4.0 * float(expected.max()), rel=1e-9)


def test_recovery_ignores_a_change_of_exponent_but_not_a_drop(generator):
    """The same per-pixel fit reported at γ = 4 and then at γ = 1 (a cloud that grew and looks at a
    quarter of the pixels) is no drop once rescaled; without the exponent it would be one."""
    told = _recovering_localizer(generator, MeasurementConfig(exponent=4.0, exponent_reference_pixels=64))
    untold = _recovering_localizer(torch.Generator().manual_seed(1234), MeasurementConfig(exponent=4.0, exponent_reference_pixels=64))
    fit = torch.full((40,), 5.0, dtype=torch.float64)  # log-likelihood per unit of γ
    for localizer, tell in ((told, True), (untold, False)):
        for gamma in (4.0, 4.0, 4.0):
            snap = localizer.snapshot()
            assert localizer.merge(snap.epoch, snap.generation, snap.ids, gamma * fit, exponent=gamma if tell else None).injected == 0
        snap = localizer.snapshot()
        report = localizer.merge(snap.epoch, snap.generation, snap.ids, 1.0 * fit, exponent=1.0 if tell else None)
        assert (report.injected == 0) is tell
    snap = told.snapshot()
    assert told.merge(snap.epoch, snap.generation, snap.ids, 1.0 * (fit - 3.0), exponent=1.0).injected > 0  # a real drop: 12 nats at γ = 4


@pytest.mark.parametrize("exponent", [0.0, -1.0, float("nan"), float("inf")])
def test_a_bad_exponent_is_refused_with_the_value(generator, exponent):
    localizer = _recovering_localizer(generator, MeasurementConfig())
    snap = localizer.snapshot()
    with pytest.raises(ValueError, match=f"exponent={exponent}"):
        localizer.merge(snap.epoch, snap.generation, snap.ids, torch.zeros(40), exponent=exponent)
