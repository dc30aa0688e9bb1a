"""Motion model (eq. 4): vectorised vs naive loop, right-multiplied odometry, noise statistics."""

from __future__ import annotations

import torch

from locnerf.filter.motion import MotionNoiseConfig, propagate_poses, sample_tangent_noise
from locnerf.filter.initialization import gaussian_particles
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
