"""Rotation averaging, tangent covariance, error metrics and pose validation."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.initialization import gaussian_particles
from locnerf.geometry import (
    InvalidPoseError,
    geodesic_rotation_mean,
    make_pose,
    rotation_error_deg,
    so3_exp,
    so3_log,
    tangent_covariance,
    translation_error,
    validate_poses,
    weighted_pose_mean,
)


def test_weighted_mean_about_one_axis_is_the_weighted_mean_angle():
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    angles = torch.tensor([0.1, 0.5, 1.2], dtype=torch.float64)
    weights = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64)
    mean = geodesic_rotation_mean(so3_exp(angles[:, None] * axis), weights)
    expected = float((weights * angles).sum())
    assert torch.allclose(so3_log(mean), expected * axis, atol=1e-10)


def test_mean_matches_brute_force_minimiser_of_geodesic_cost(generator):
    """Oracle: gradient-free search for the minimiser of Σ w d(R, R_i)² around the result."""
    rotations = so3_exp(torch.randn(30, 3, dtype=torch.float64, generator=generator) * 0.6)
    weights = torch.rand(30, dtype=torch.float64, generator=generator)
    mean = geodesic_rotation_mean(rotations, weights)

    def cost(r: torch.Tensor) -> float:
        return float((weights * so3_log(r.transpose(-1, -2) @ rotations).norm(dim=-1) ** 2).sum())

    probes = so3_exp(torch.randn(400, 3, dtype=torch.float64, generator=generator) * 0.01)
    assert all(cost(mean @ p) >= cost(mean) - 1e-12 for p in probes)


def test_zero_weight_rotations_are_ignored(generator):
    rotations = so3_exp(torch.randn(5, 3, dtype=torch.float64, generator=generator))
    weights = torch.tensor([0.0, 1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    assert torch.allclose(geodesic_rotation_mean(rotations, weights), rotations[1], atol=1e-10)


def test_widely_spread_and_antipodal_sets_still_return_a_rotation(generator):
    wide = so3_exp(torch.randn(200, 3, dtype=torch.float64, generator=generator) * 3.0)
    antipodal = torch.stack([torch.eye(3, dtype=torch.float64), so3_exp(torch.tensor([math.pi, 0.0, 0.0], dtype=torch.float64))])
    for rotations in (wide, antipodal):
        mean = geodesic_rotation_mean(rotations, max_iterations=5)
        assert torch.allclose(mean.T @ mean, torch.eye(3, dtype=torch.float64), atol=1e-9)
        assert abs(torch.linalg.det(mean).item() - 1.0) < 1e-9


def test_pose_mean_and_tangent_covariance_recover_a_gaussian(generator):
    mean = make_pose(so3_exp(torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    sigmas = torch.tensor([0.05, 0.02, 0.08, 0.1, 0.03, 0.06], dtype=torch.float64)
    samples = gaussian_particles(mean, torch.diag(sigmas**2), 20000, generator)
    estimate = weighted_pose_mean(samples)
    assert translation_error(estimate, mean) < 0.005
    assert rotation_error_deg(estimate, mean) < 0.2
    covariance = tangent_covariance(samples, estimate)
    # Tolerance: 20000 samples give a relative standard error of about 1 % on each variance;
    # the translation variances also pick up the rotation-translation coupling of Exp (< 5 %).
    assert torch.allclose(covariance.diagonal().sqrt(), sigmas, rtol=0.06)


def test_metrics_hand_values():
    a = torch.eye(4, dtype=torch.float64)
    b = make_pose(so3_exp(torch.tensor([0.0, math.radians(30.0), 0.0], dtype=torch.float64)), torch.tensor([3.0, 4.0, 0.0], dtype=torch.float64))
    assert translation_error(a, b).item() == pytest.approx(5.0)
    assert rotation_error_deg(a, b).item() == pytest.approx(30.0)


@pytest.mark.parametrize(
    "pose,message",
    [
        (torch.eye(3), "shape"),
        (torch.full((4, 4), float("nan")), "NaN"),
        (torch.diag(torch.tensor([2.0, 1.0, 1.0, 1.0])), "orthonormal"),
        (torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0])), "determinant"),
        (torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]]), "last row"),
    ],
)
def test_invalid_poses_are_refused_with_reason(pose, message):
    with pytest.raises(InvalidPoseError, match=message):
        validate_poses(pose)
