"""Adaptive tempering: the exponent against a brute-force scan, its edge cases, and the localizer's use
of it (a sharp update on a spread cloud keeps at least ρN effective particles). Seeded."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import ValidationError

from locnerf.filter.annealing import AnnealingConfig, AnnealingStage
from locnerf.filter.convergence_protection import ConvergenceProtectionConfig
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig
from locnerf.filter.particles import normalise_log_weights
from locnerf.filter.resampling import effective_sample_size
from locnerf.filter.tempering import TemperingConfig, tempering_exponent
from locnerf.geometry import make_pose, so3_exp


def ess_fraction(log_weights: torch.Tensor) -> float:
    return effective_sample_size(torch.exp(normalise_log_weights(log_weights))) / log_weights.numel()


def brute_force_exponent(log_weights: torch.Tensor, log_likelihoods: torch.Tensor, rho: float, steps: int = 20000) -> float:
    """The largest β on a fine grid of (0, 1] whose ESS is at least ρN (naive oracle)."""
    best = 0.0
    for k in range(1, steps + 1):
        beta = k / steps
        if ess_fraction(log_weights + beta * log_likelihoods) >= rho:
            best = beta
    return best


@pytest.mark.parametrize("rho", [0.1, 0.3, 0.6])
def test_exponent_matches_a_brute_force_scan(rho):
    generator = torch.Generator().manual_seed(0)
    log_weights = normalise_log_weights(torch.zeros(400, dtype=torch.float64))
    log_likelihoods = 16.0 * torch.randn(400, generator=generator, dtype=torch.float64)  # a sharp update: ESS of a few particles
    assert ess_fraction(log_weights + log_likelihoods) < 0.05
    beta = tempering_exponent(log_weights, log_likelihoods, rho)
    assert beta == pytest.approx(brute_force_exponent(log_weights, log_likelihoods, rho), abs=1e-4)  # the grid's step is 5e-5
    assert ess_fraction(log_weights + beta * log_likelihoods) == pytest.approx(rho, abs=1e-3)


def test_a_gentle_update_is_not_tempered_and_impossible_targets_are_left_alone():
    generator = torch.Generator().manual_seed(1)
    uniform = normalise_log_weights(torch.zeros(200, dtype=torch.float64))
    gentle = 0.1 * torch.randn(200, generator=generator, dtype=torch.float64)
    assert tempering_exponent(uniform, gentle, 0.5) == 1.0
    # Weights already below ρN effective particles: no β can reach ρ, so the update goes in whole.
    skewed = normalise_log_weights(torch.cat([torch.zeros(5), torch.full((195,), -30.0)]).double())
    assert ess_fraction(skewed) < 0.5
    assert tempering_exponent(skewed, 16.0 * torch.randn(200, generator=generator, dtype=torch.float64), 0.5) == 1.0


def test_minus_infinity_stays_and_huge_likelihoods_do_not_overflow():
    log_weights = normalise_log_weights(torch.zeros(100, dtype=torch.float64))
    log_likelihoods = torch.linspace(0.0, 5000.0, 100, dtype=torch.float64)
    log_likelihoods[:10] = -math.inf
    beta = tempering_exponent(log_weights, log_likelihoods, 0.2)
    assert 0.0 < beta < 1.0
    tempered = log_weights + torch.where(torch.isfinite(log_likelihoods), beta * log_likelihoods, log_likelihoods)
    assert ess_fraction(tempered) >= 0.2 - 1e-6
    assert bool(torch.isneginf(tempered[:10]).all())


def test_bad_settings_are_refused_naming_the_value():
    for bad in (0.0, 1.0, 1.5):
        with pytest.raises(ValidationError, match="min_ess_fraction"):
            TemperingConfig(min_ess_fraction=bad)
    with pytest.raises(ValueError, match="min_ess_fraction=1.0"):
        tempering_exponent(torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), 1.0)
    with pytest.raises(ValueError, match="expected two"):
        tempering_exponent(torch.zeros(3, dtype=torch.float64), torch.zeros(4, dtype=torch.float64), 0.5)


def spread_cloud(count: int, generator: torch.Generator) -> torch.Tensor:
    positions = 2 * torch.rand(count, 3, dtype=torch.float64, generator=generator) - 1
    yaw = (2 * torch.rand(count, dtype=torch.float64, generator=generator) - 1) * math.pi
    return make_pose(so3_exp(torch.stack([torch.zeros_like(yaw), yaw, torch.zeros_like(yaw)], -1)), positions)


def distinct_parents_after_a_sharp_update(tempering: TemperingConfig, annealing: AnnealingConfig) -> tuple[int, Localizer]:
    generator = torch.Generator().manual_seed(3)
    config = LocalizerConfig(particles=600, convergence_protection=ConvergenceProtectionConfig(count=0), annealing=annealing, tempering=tempering)
    localizer = Localizer(config, generator, dtype=torch.float64)
    start = spread_cloud(600, generator)
    localizer.initialize(start)
    snap = localizer.snapshot()
    sharp = -200.0 * start[:, :3, 3].norm(dim=-1)  # γ-like sharpness: only the few particles nearest the origin count
    localizer.merge(snap.epoch, snap.generation, snap.ids, sharp)
    return len(set(localizer.particles.parent_ids.tolist())), localizer


def test_the_localizer_keeps_a_spread_cloud_alive():
    """Untempered, the sharp update leaves a handful of parents; tempered at ρ = 0.25 the resampling
    draws 600 children from ≥ 150 effective particles, so well over 100 distinct parents survive
    (multinomial: about 150·(1 − e⁻¹) ≥ 95 expected from the effective ones alone; tolerance seeded)."""
    annealing = AnnealingConfig(enabled=False)  # the stage stays COARSE
    plain, _ = distinct_parents_after_a_sharp_update(TemperingConfig(), annealing)
    tempered, localizer = distinct_parents_after_a_sharp_update(TemperingConfig(min_ess_fraction=0.25), annealing)
    assert plain < 20
    assert tempered > 100
    assert localizer.counters["tempered"] == 1


def test_coarse_only_leaves_converged_updates_alone():
    annealing = AnnealingConfig(alpha_refine=10.0, alpha_super_refine=5.0)  # every cloud counts as converged
    parents, localizer = distinct_parents_after_a_sharp_update(TemperingConfig(min_ess_fraction=0.25), annealing)
    assert localizer.stage != AnnealingStage.COARSE
    # The first merge happens in the COARSE stage of a fresh filter; the next one is converged and untempered.
    snap = localizer.snapshot()
    sharp = -200.0 * snap.poses[:, :3, 3].norm(dim=-1)
    localizer.merge(snap.epoch, snap.generation, snap.ids, sharp)
    assert localizer.counters["tempered"] == 1
    assert parents > 0
