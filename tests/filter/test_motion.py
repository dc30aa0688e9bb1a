"""Motion model (eq. 4): vectorised vs naive loop, right-multiplied odometry, noise statistics."""

from __future__ import annotations

import torch

from locnerf.filter.initialization import gaussian_particles
from locnerf.filter.motion import MotionNoiseConfig, propagate_poses, sample_tangent_noise
from locnerf.geometry import make_pose, se3_exp, se3_log, so3_exp


def test_vectorised_prediction_matches_a_naive_loop(generator):
    poses = gaussian_particles(torch.eye(4, dtype=torch.float64), torch.eye(6, dtype=torch.float64) * 0.1, 50, generator)
    odometry = make_pose(so3_exp(torch.tensor([0.0, 0.1, 0.0], dtype=torch.float64)), torch.tensor([0.0, 0.0, -0.2], dtype=torch.float64))
    sigma = MotionNoiseConfig(rotation_sigma=(0.02, 0.03, 0.01), translation_sigma=(0.01, 0.02, 0.03)).sigma_vector()
    moved = propagate_poses(poses, odometry, sigma, torch.Generator().manual_seed(7))
    noise = sample_tangent_noise(50, sigma, torch.Generator().manual_seed(7))
    for i in range(50):
        expected = poses[i] @ odometry @ se3_exp(noise[i])
        assert torch.allclose(moved[i], expected, atol=1e-12)


def test_odometry_acts_in_each_particle_body_frame(generator):
    # A particle facing +x (rotated -90° about y) that moves 1 unit forward (-z in its camera frame).
    facing_x = make_pose(so3_exp(torch.tensor([0.0, -torch.pi / 2, 0.0], dtype=torch.float64)), torch.zeros(3, dtype=torch.float64))
    forward = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    moved = propagate_poses(facing_x[None], forward, torch.zeros(6, dtype=torch.float64), generator)
    assert torch.allclose(moved[0, :3, 3], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), atol=1e-12)


def test_noise_covariance_matches_configuration(generator):
    sigma = MotionNoiseConfig(rotation_sigma=(0.01, 0.04, 0.01), translation_sigma=(0.02, 0.02, 0.05)).sigma_vector()
    start = torch.eye(4, dtype=torch.float64).expand(20000, 4, 4)
    moved = propagate_poses(start, None, sigma, generator)
    std = se3_log(moved).std(dim=0)
    # 20000 samples: the relative standard error of a standard deviation is about 0.5 %.
    assert torch.allclose(std, sigma, rtol=0.03)


def test_zero_noise_is_exact_and_does_not_alias_input(generator):
    poses = torch.eye(4, dtype=torch.float64).expand(3, 4, 4).clone()
    moved = propagate_poses(poses, None, torch.zeros(6, dtype=torch.float64), generator)
    moved[0, 0, 3] = 5.0
    assert poses[0, 0, 3] == 0.0


def test_pivot_noise_swings_the_camera_about_the_point_it_looks_at(generator):
    """With only pivot noise, every moved camera still sees the pivot point straight ahead at the
    same depth: P·Exp(θ)·P⁻¹ is a rotation about that point."""
    config = MotionNoiseConfig(rotation_sigma=(0.0,) * 3, translation_sigma=(0.0,) * 3, pivot_depth=4.0, pivot_sigma=(0.05, 0.08))
    start = make_pose(so3_exp(torch.tensor([0.2, -0.7, 0.1], dtype=torch.float64)), torch.tensor([1.0, 2.0, -3.0], dtype=torch.float64))
    moved = propagate_poses(start.expand(500, 4, 4), None, config.sigma_vector(), generator, config.pivot_noise())
    ahead = torch.tensor([0.0, 0.0, -4.0, 1.0], dtype=torch.float64)
    pivot = start @ ahead
    torch.testing.assert_close(moved @ ahead, pivot.expand(500, 4), rtol=0, atol=1e-9)
    # ... and the cameras did move: sideways by about depth × angle (σ 0.2 and 0.32 units).
    assert (moved[:, :3, 3] - start[:3, 3]).norm(dim=-1).median() > 0.1


def test_pivot_noise_covariance_matches_its_samples(generator):
    """20000 draws of δ with axis and pivot noise: sample covariance against
    diag(σ²) + A diag(σ_p²) Aᵀ within 0.03 of sqrt(Σ_ii Σ_jj) (standard error ~0.007)."""
    config = MotionNoiseConfig(rotation_sigma=(0.01, 0.02, 0.01), translation_sigma=(0.02, 0.01, 0.03), pivot_depth=3.0, pivot_sigma=(0.02, 0.01))
    pivot = config.pivot_noise()
    start = torch.eye(4, dtype=torch.float64).expand(20000, 4, 4)
    moved = propagate_poses(start, None, config.sigma_vector(), generator, pivot)
    tangents = se3_log(moved)
    sampled = torch.cov(tangents.T)
    expected = torch.diag(config.sigma_vector() ** 2) + pivot.covariance()
    scale = torch.sqrt(torch.diagonal(expected)[:, None] * torch.diagonal(expected)[None, :])
    assert float(((sampled - expected).abs() / scale).max()) < 0.03


def test_pivot_noise_is_absent_by_default_and_scales_with_annealing():
    assert MotionNoiseConfig().pivot_noise() is None
    pivot = MotionNoiseConfig(pivot_depth=2.0, pivot_sigma=(0.02, 0.04)).pivot_noise(0.25)
    torch.testing.assert_close(pivot.sigma, torch.tensor([0.005, 0.01], dtype=torch.float64))
    assert pivot.depth == 2.0


def test_long_float32_prediction_keeps_rotations_orthonormal():
    """20 000 noisy float32 compositions (over 20 min at 15 Hz): |RᵀR − I| stays under 5e-6
    (the workers refuse 1e-3)."""
    from locnerf.filter.motion import propagate_poses

    generator = torch.Generator().manual_seed(0)
    poses = torch.eye(4).expand(16, 4, 4).clone()
    sigma = torch.tensor([0.01, 0.02, 0.01, 0.005, 0.005, 0.005], dtype=torch.float64)
    for _ in range(20000):
        poses = propagate_poses(poses, None, sigma, generator)
    rotation = poses[:, :3, :3].double()
    assert float((rotation.transpose(-1, -2) @ rotation - torch.eye(3, dtype=torch.float64)).abs().max()) < 5e-6
