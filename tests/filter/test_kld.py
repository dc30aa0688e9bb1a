"""KLD-sampling (Fox 2003): the bound, sample sizes for concentrated and spread posteriors, and
its use by the localizer without breaking merge-by-ancestor. Seeded; each statistical check says
its tolerance."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.annealing import AnnealingConfig
from locnerf.filter.convergence_protection import ConvergenceProtectionConfig
from locnerf.filter.kld import KldConfig, kld_bound, kld_resample
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig
from locnerf.filter.resampling import multinomial_resample, systematic_resample
from locnerf.geometry import make_pose, so3_exp

KLD = KldConfig(enabled=True, epsilon=0.05, z=2.326, min_particles=100, bin_translation=0.02, bin_rotation_deg=2.0)


def fox(k: int, epsilon: float, z: float) -> float:
    """The bound written out for one k (naive oracle)."""
    a = 2.0 / (9.0 * (k - 1))
    return (k - 1) / (2.0 * epsilon) * (1.0 - a + math.sqrt(a) * z) ** 3


def test_bound_matches_hand_worked_values():
    # k = 2: a = 2/9, 1 - 2/9 + sqrt(2/9)·2.326 = 1.87432..., cubed 6.58404..., times 1/(2·0.05) = 10.
    bound = kld_bound(torch.tensor([1, 2, 10, 100]), 0.05, 2.326)
    assert bound.tolist() == pytest.approx([0.0, 65.8404, 216.9395, 1346.4903], abs=1e-3)
    assert float(kld_bound(torch.tensor(10), 0.01, 0.99)) == pytest.approx(fox(10, 0.01, 0.99), rel=1e-12)
    assert float(kld_bound(torch.tensor(10), 0.01, 0.99)) == pytest.approx(650.808, abs=1e-3)


def poses(positions: torch.Tensor, rotvecs: torch.Tensor) -> torch.Tensor:
    return make_pose(so3_exp(rotvecs), positions)


def concentrated(count: int, generator: torch.Generator) -> torch.Tensor:
    """Inside one cell: positions in [0.002, 0.018]³, rotation vectors in [0.2°, 1.8°]³."""
    positions = 0.002 + 0.016 * torch.rand(count, 3, dtype=torch.float64, generator=generator)
    rotvecs = math.radians(0.2) + math.radians(1.6) * torch.rand(count, 3, dtype=torch.float64, generator=generator)
    return poses(positions, rotvecs)


def spread(count: int, generator: torch.Generator) -> torch.Tensor:
    """Global-localization-like: positions uniform in a 2-unit cube, yaw uniform."""
    positions = 2 * torch.rand(count, 3, dtype=torch.float64, generator=generator) - 1
    yaw = (2 * torch.rand(count, dtype=torch.float64, generator=generator) - 1) * math.pi
    return poses(positions, torch.stack([torch.zeros_like(yaw), yaw, torch.zeros_like(yaw)], -1))


@pytest.mark.parametrize("resampler", [multinomial_resample, systematic_resample])
def test_concentrated_posterior_keeps_min_particles_and_spread_one_max(resampler):
    generator = torch.Generator().manual_seed(0)
    weights = torch.full((2000,), 1 / 2000, dtype=torch.float64)
    one_cell = kld_resample(weights, concentrated(2000, generator), KLD, 2000, resampler, generator)
    assert one_cell.numel() == 100  # one occupied cell: bound 0, so exactly min_particles
    everywhere = kld_resample(weights, spread(2000, generator), KLD, 2000, resampler, generator)
    assert everywhere.numel() == 2000  # nearly every draw a new cell: the bound exceeds the maximum


def test_tracking_like_posterior_needs_a_few_hundred():
    """σ = 0.01 units and 0.3° around a pose: a few position cells per axis; the count lands well
    between the bounds (tolerance: 100 < n < 1000 of 2000, seeded)."""
    generator = torch.Generator().manual_seed(1)
    positions = torch.tensor([0.5, 0.2, 4.0], dtype=torch.float64) + 0.01 * torch.randn(2000, 3, dtype=torch.float64, generator=generator)
    rotvecs = torch.tensor([0.3, 1.0, 0.1], dtype=torch.float64) + math.radians(0.3) * torch.randn(2000, 3, dtype=torch.float64, generator=generator)
    weights = torch.full((2000,), 1 / 2000, dtype=torch.float64)
    kept = kld_resample(weights, poses(positions, rotvecs), KLD, 2000, multinomial_resample, generator)
    assert 100 < kept.numel() < 1000


def test_localizer_shrinks_on_convergence_and_late_results_still_merge_by_ancestor():
    generator = torch.Generator().manual_seed(2)
    config = LocalizerConfig(particles=1500, kld=KLD, convergence_protection=ConvergenceProtectionConfig(count=0), annealing=AnnealingConfig(enabled=False))
    localizer = Localizer(config, generator, dtype=torch.float64)
    start = torch.cat([concentrated(30, generator), spread(1470, generator)])
    localizer.initialize(start)
    late = localizer.snapshot()
    early = localizer.snapshot()
    # The first result favours the 30 concentrated particles: the posterior collapses into one cell.
    favoured = torch.where(torch.arange(1500) < 30, 0.0, -50.0).double()
    report = localizer.merge(early.epoch, early.generation, early.ids, favoured)
    assert report.outcome == "merged" and report.particle_count == 100
    survivors = localizer.particles
    assert bool((survivors.parent_ids < 30).all())  # every child descends from a favoured particle
    assert len(set(survivors.ids.tolist())) == 100 and int(survivors.ids.min()) >= 1500  # fresh unique ids
    # A result computed on the older snapshot arrives after the shrink: it reaches every child through its ancestor.
    ancestor_ll = -torch.arange(1500, dtype=torch.float64)
    late_report = localizer.merge(late.epoch, late.generation, late.ids, ancestor_ll)
    assert late_report.outcome == "merged"
    assert localizer.particles.count == 100
    assert localizer.counters == dict.fromkeys(localizer.counters, 0) | {"merged": 2}


def test_kld_is_off_by_default():
    assert LocalizerConfig().kld.enabled is False
