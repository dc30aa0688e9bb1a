"""The estimate carried by one prediction step against the estimate of the moved particles."""

import torch

from locnerf.filter.annealing import AnnealingStage
from locnerf.filter.estimate import ParticleEstimate, carry_estimate
from locnerf.filter.initialization import gaussian_particles
from locnerf.filter.motion import PivotNoise, propagate_poses
from locnerf.geometry import make_pose, rotation_error_deg, translation_error
from locnerf.geometry.averaging import weighted_pose_mean_and_covariance
from locnerf.geometry.so3 import so3_exp

PARTICLES = 400_000


def _monte_carlo(mean: torch.Tensor, covariance: torch.Tensor, increment: torch.Tensor | None, sigma: torch.Tensor, seed: int, pivot: PivotNoise | None = None):
    generator = torch.Generator().manual_seed(seed)
    poses = propagate_poses(gaussian_particles(mean, covariance, PARTICLES, generator), increment, sigma, generator, pivot)
    return weighted_pose_mean_and_covariance(poses, torch.full((PARTICLES,), 1.0 / PARTICLES, dtype=torch.float64), 1e-10)


def _estimate(mean: torch.Tensor, covariance: torch.Tensor) -> ParticleEstimate:
    return ParticleEstimate(mean, covariance, spread=0.0, effective_sample_size=1.0, particle_count=1, stage=AnnealingStage.COARSE)


def _correlated_covariance() -> torch.Tensor:
    stds = torch.tensor([0.02, 0.03, 0.015, 0.01, 0.02, 0.012], dtype=torch.float64)
    correlation = torch.eye(6, dtype=torch.float64)
    correlation[0, 4] = correlation[4, 0] = 0.6
    correlation[2, 3] = correlation[3, 2] = -0.4
    return stds[:, None] * correlation * stds[None, :]


def _assert_close_covariance(carried: torch.Tensor, sampled: torch.Tensor, relative: float) -> None:
    """Entry-wise, relative to sqrt(Σ_ii Σ_jj) of the sampled covariance (correlation scale)."""
    scale = torch.sqrt(torch.diagonal(sampled)[:, None] * torch.diagonal(sampled)[None, :])
    worst = float(((carried - sampled).abs() / scale).max())
    assert worst < relative, f"largest correlation-scale difference {worst:.4f} (tolerance {relative})"


def test_carried_estimate_matches_the_moved_particles() -> None:
    """Tolerance: 0.03 of sqrt(Σ_ii Σ_jj); the sampling error at 4e5 particles is ~0.003 and
    the first-order model's error at these spreads (0.03 rad, 0.5-unit increment) ~0.01."""
    mean = make_pose(so3_exp(torch.tensor([0.3, -1.1, 0.4], dtype=torch.float64)), torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64))
    increment = make_pose(so3_exp(torch.tensor([0.1, 0.25, -0.2], dtype=torch.float64)), torch.tensor([0.4, -0.1, 0.3], dtype=torch.float64))
    sigma = torch.tensor([0.01, 0.02, 0.005, 0.004, 0.006, 0.01], dtype=torch.float64)
    covariance = _correlated_covariance()
    carried = carry_estimate(_estimate(mean, covariance), increment, sigma)
    sampled_mean, sampled_covariance = _monte_carlo(mean, covariance, increment, sigma, seed=0)
    assert float(translation_error(carried.pose, sampled_mean)) < 1e-3
    assert float(rotation_error_deg(carried.pose, sampled_mean)) < 0.01
    _assert_close_covariance(carried.covariance, sampled_covariance, 0.03)
    expected_spread = torch.sqrt(torch.diagonal(carried.pose[:3, :3] @ carried.covariance[3:, 3:] @ carried.pose[:3, :3].T)).max()
    assert abs(carried.spread - float(expected_spread)) < 1e-12


def test_noise_only_step_keeps_the_pose_and_adds_the_noise() -> None:
    mean = make_pose(so3_exp(torch.tensor([0.0, 0.5, 0.0], dtype=torch.float64)), torch.tensor([0.2, 0.0, -1.0], dtype=torch.float64))
    sigma = torch.tensor([0.01, 0.01, 0.01, 0.005, 0.005, 0.005], dtype=torch.float64)
    covariance = _correlated_covariance()
    carried = carry_estimate(_estimate(mean, covariance), None, sigma)
    assert torch.equal(carried.pose, mean)
    assert torch.allclose(carried.covariance, covariance + torch.diag(sigma**2), atol=0, rtol=1e-15)
    _, sampled_covariance = _monte_carlo(mean, covariance, None, sigma, seed=1)
    _assert_close_covariance(carried.covariance, sampled_covariance, 0.03)


def test_carried_estimate_includes_the_pivot_noise() -> None:
    """Same tolerance as above, with pivot noise (σ 0.02 / 0.01 rad at depth 3) on top of δ."""
    mean = make_pose(so3_exp(torch.tensor([0.3, -1.1, 0.4], dtype=torch.float64)), torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64))
    increment = make_pose(so3_exp(torch.tensor([0.1, 0.25, -0.2], dtype=torch.float64)), torch.tensor([0.4, -0.1, 0.3], dtype=torch.float64))
    sigma = torch.tensor([0.01, 0.02, 0.005, 0.004, 0.006, 0.01], dtype=torch.float64)
    pivot = PivotNoise(3.0, torch.tensor([0.02, 0.01], dtype=torch.float64))
    carried = carry_estimate(_estimate(mean, _correlated_covariance()), increment, sigma, pivot)
    _, sampled_covariance = _monte_carlo(mean, _correlated_covariance(), increment, sigma, seed=2, pivot=pivot)
    _assert_close_covariance(carried.covariance, sampled_covariance, 0.03)
