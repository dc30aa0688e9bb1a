"""Resamplers as pure functions: frequencies follow weights, systematic is low-variance."""

from __future__ import annotations

import pytest
import torch

from locnerf.filter.resampling import effective_sample_size, multinomial_resample, systematic_resample

WEIGHTS = torch.tensor([0.5, 0.25, 0.125, 0.125, 0.0])


def test_multinomial_frequencies_follow_weights(generator):
    counts = torch.bincount(multinomial_resample(WEIGHTS, 40000, generator), minlength=5).double() / 40000
    # Binomial standard error at n = 40000 is at most 0.0025; allow four of them.
    assert torch.allclose(counts, WEIGHTS.double(), atol=0.01)
    assert counts[4] == 0


def test_systematic_draws_each_particle_floor_or_ceil_of_expected(generator):
    weights = torch.rand(50, generator=generator)
    weights /= weights.sum()
    for _ in range(20):
        counts = torch.bincount(systematic_resample(weights, 200, generator), minlength=50).double()
        expected = weights.double() * 200
        assert ((counts >= torch.floor(expected) - 1e-9) & (counts <= torch.ceil(expected) + 1e-9)).all()


@pytest.mark.parametrize("resampler", [multinomial_resample, systematic_resample])
@pytest.mark.parametrize(
    "weights,message",
    [(torch.zeros(4), "all zero"), (torch.tensor([float("nan"), 1.0]), "finite"), (torch.tensor([-1.0, 2.0]), "non-negative"), (torch.zeros(0), "N>=1")],
)
def test_bad_weights_are_refused(resampler, weights, message, generator):
    with pytest.raises(ValueError, match=message):
        resampler(weights, 4, generator)


def test_effective_sample_size():
    assert effective_sample_size(torch.full((10,), 0.1)) == pytest.approx(10.0)
    assert effective_sample_size(torch.tensor([1.0, 0.0, 0.0])) == pytest.approx(1.0)
