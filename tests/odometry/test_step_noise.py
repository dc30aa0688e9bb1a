"""The odometry's per-step error that sets the prediction noise: the δ of eq. 4 recovered exactly, its σ per axis."""

from __future__ import annotations

import pytest
import torch

from locnerf.geometry import pose_inverse, se3_exp
from locnerf.odometry.step_noise import step_errors, step_noise

SIGMA = torch.tensor([0.002, 0.003, 0.001, 0.005, 0.002, 0.004], dtype=torch.float64)


def _truth_and_odometry(steps: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A random walk of true poses and an odometry whose every increment O_t = G_t · Exp(δ_t)⁻¹, so
    that G_t = O_t · Exp(δ_t) (eq. 4 exact with δ_t); δ_t ~ N(0, diag(SIGMA²))."""
    generator = torch.Generator().manual_seed(seed)
    motion = torch.randn(steps, 6, dtype=torch.float64, generator=generator) * torch.tensor([0.02, 0.02, 0.02, 0.01, 0.01, 0.01], dtype=torch.float64)
    delta = torch.randn(steps, 6, dtype=torch.float64, generator=generator) * SIGMA
    truth, odometry = [torch.eye(4, dtype=torch.float64)], [torch.eye(4, dtype=torch.float64)]
    for g, d in zip(se3_exp(motion), se3_exp(delta)):
        truth.append(truth[-1] @ g)
        odometry.append(odometry[-1] @ g @ pose_inverse(d))
    # The odometry lives in its own frame: moving it rigidly changes nothing.
    offset = se3_exp(torch.tensor([0.3, -0.2, 0.1, 1.0, 2.0, -0.5], dtype=torch.float64))
    return offset @ torch.stack(odometry), torch.stack(truth), delta


def test_step_errors_recover_the_delta_of_eq4():
    odometry, truth, delta = _truth_and_odometry(50, 0)
    valid = torch.ones(51, dtype=torch.bool)
    torch.testing.assert_close(step_errors(odometry, valid, truth), delta, atol=1e-10, rtol=0)


def test_a_gap_drops_the_two_steps_that_touch_it():
    odometry, truth, delta = _truth_and_odometry(20, 1)
    valid = torch.ones(21, dtype=torch.bool)
    valid[5] = False  # steps 4 (4 -> 5) and 5 (5 -> 6) touch stamp 5
    keep = [k for k in range(20) if k not in (4, 5)]
    torch.testing.assert_close(step_errors(odometry, valid, truth), delta[keep], atol=1e-10, rtol=0)


def test_sigma_per_axis_matches_the_drawn_noise():
    odometry, truth, _ = _truth_and_odometry(4000, 2)
    noise = step_noise(odometry, torch.ones(4001, dtype=torch.bool), truth)
    assert noise["steps"] == 4000
    measured = torch.tensor(noise["rotation_sigma"] + noise["translation_sigma"], dtype=torch.float64)
    robust = torch.tensor(noise["rotation_sigma_robust"] + noise["translation_sigma_robust"], dtype=torch.float64)
    # 4000 draws: the standard deviation's relative error is ~1/√8000 ≈ 1.1 %, the MAD's ~1.9 %; 6 % is > 3 of those.
    torch.testing.assert_close(measured, SIGMA, rtol=0.05, atol=0)
    torch.testing.assert_close(robust, SIGMA, rtol=0.08, atol=0)
    assert all(abs(m) < 4 * s / 4000**0.5 for m, s in zip(noise["rotation_mean"] + noise["translation_mean"], SIGMA.tolist()))


def test_no_consecutive_valid_stamps_is_refused():
    odometry, truth, _ = _truth_and_odometry(3, 3)
    with pytest.raises(ValueError, match="no two consecutive valid stamps"):
        step_errors(odometry, torch.tensor([True, False, True, False]), truth)
