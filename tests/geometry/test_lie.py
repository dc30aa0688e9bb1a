"""SO(3)/SE(3) exp/log against matrix-exponential oracles, round trips and edge angles."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.geometry import hat, se3_exp, se3_log, so3_exp, so3_log, vee


def twist_matrix(xi: torch.Tensor) -> torch.Tensor:
    """4×4 Lie-algebra matrix of (ω, ρ), the input of the matrix-exponential oracle."""
    m = torch.zeros(*xi.shape[:-1], 4, 4, dtype=xi.dtype)
    m[..., :3, :3] = hat(xi[..., :3])
    m[..., :3, 3] = xi[..., 3:]
    return m


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-6)])
def test_so3_exp_matches_matrix_exponential(dtype, tol, generator):
    omega = torch.randn(500, 3, dtype=torch.float64, generator=generator) * 1.5
    oracle = torch.linalg.matrix_exp(hat(omega))
    assert (so3_exp(omega.to(dtype)).double() - oracle).abs().max() < tol


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-11), (torch.float32, 5e-6)])
def test_se3_exp_matches_matrix_exponential(dtype, tol, generator):
    xi = torch.randn(500, 6, dtype=torch.float64, generator=generator)
    oracle = torch.linalg.matrix_exp(twist_matrix(xi))
    assert (se3_exp(xi.to(dtype)).double() - oracle).abs().max() < tol


@pytest.mark.parametrize("scale", [1e-9, 1e-5, 1e-3 * 0.99, 1e-3 * 1.01, 0.5, 2.0, math.pi - 1e-6])
def test_so3_log_inverts_exp_across_angles(scale, generator):
    axis = torch.randn(200, 3, dtype=torch.float64, generator=generator)
    omega = axis / axis.norm(dim=-1, keepdim=True) * scale
    assert (so3_log(so3_exp(omega)) - omega).abs().max() < 1e-9 * max(1.0, scale) + 1e-15


def test_so3_log_at_half_turn_returns_a_valid_rotation_vector():
    omega = torch.tensor([[math.pi, 0.0, 0.0], [0.0, 0.0, -math.pi], [math.pi / math.sqrt(2), math.pi / math.sqrt(2), 0.0]], dtype=torch.float64)
    recovered = so3_log(so3_exp(omega))
    assert torch.allclose(recovered.norm(dim=-1), torch.full((3,), math.pi, dtype=torch.float64), atol=1e-9)
    assert (so3_exp(recovered) - so3_exp(omega)).abs().max() < 1e-12


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 2e-4)])
def test_se3_log_round_trip(dtype, tol, generator):
    xi = torch.randn(500, 6, dtype=torch.float64, generator=generator)
    xi[:, :3] *= 0.9  # keep |ω| < π so that log(exp(ξ)) = ξ
    xi[:, :3] = xi[:, :3] / xi[:, :3].norm(dim=-1, keepdim=True).clamp_min(1.0) * 2.5
    assert (se3_log(se3_exp(xi.to(dtype))).double() - xi).abs().max() < tol


def test_small_angles_keep_float32_precision():
    omega = torch.tensor([[1e-7, -2e-7, 3e-7]], dtype=torch.float32)
    assert torch.allclose(so3_log(so3_exp(omega)), omega, rtol=1e-3, atol=1e-12)
    xi = torch.tensor([[1e-8, 0.0, 0.0, 0.1, 0.2, 0.3]], dtype=torch.float32)
    assert torch.allclose(se3_log(se3_exp(xi)), xi, atol=1e-7)


def test_tangent_order_is_rotation_then_translation():
    pure_rotation = se3_exp(torch.tensor([0.3, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64))
    assert torch.allclose(pure_rotation[:3, 3], torch.zeros(3, dtype=torch.float64))
    assert abs(pure_rotation[1, 1].item() - math.cos(0.3)) < 1e-12
    pure_translation = se3_exp(torch.tensor([0.0, 0.0, 0.0, 1.0, 2.0, 3.0], dtype=torch.float64))
    assert torch.allclose(pure_translation[:3, 3], torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    assert torch.allclose(pure_translation[:3, :3], torch.eye(3, dtype=torch.float64))


def test_hat_vee_and_cross_product(generator):
    a, b = torch.randn(2, 10, 3, dtype=torch.float64, generator=generator)
    assert torch.allclose((hat(a) @ b[..., None]).squeeze(-1), torch.linalg.cross(a, b))
    assert torch.allclose(vee(hat(a)), a)
