"""Resamplers: pure functions from normalised weights to the indices of the particles kept.

Each takes weights ``(N,)`` (non-negative, summing to one), the number of draws ``K`` (which may
differ from N: the annealing reduces the particle count by resampling), and a ``torch.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import torch

Resampler = Callable[[torch.Tensor, int, torch.Generator], torch.Tensor]
ResamplerName = Literal["multinomial", "systematic"]


def _check(weights: torch.Tensor, count: int) -> None:
    if weights.ndim != 1 or weights.numel() == 0:
        raise ValueError(f"weights: expected shape (N>=1,), got {tuple(weights.shape)}")
    if not torch.isfinite(weights).all() or (weights < 0).any():
        raise ValueError("weights: expected finite non-negative values")
    if float(weights.sum()) <= 0:
        raise ValueError("weights: all zero; expected a positive sum")
    if count < 1:
        raise ValueError(f"count={count}: expected at least one draw")


def multinomial_resample(weights: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """K independent draws with replacement, P(i) = w_i (the paper's resampler). Returns (K,) int64."""
    _check(weights, count)
    return torch.multinomial(weights.double().cpu(), count, replacement=True, generator=generator).to(weights.device)


def systematic_resample(weights: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """Low-variance resampling: one uniform offset u, K evenly spaced pointers (u + k)/K into the CDF.

    Particle i is drawn either floor(K w_i) or ceil(K w_i) times. Returns (K,) int64.
    """
    _check(weights, count)
    w = weights.double().cpu()
    cdf = torch.cumsum(w / w.sum(), dim=0)
    cdf[-1] = 1.0  # guard against round-off leaving the last pointer past the end
    offset = torch.rand((), dtype=torch.float64, generator=generator)
    pointers = (offset + torch.arange(count, dtype=torch.float64)) / count
    return torch.searchsorted(cdf, pointers, right=True).clamp_(max=w.numel() - 1).to(weights.device)


RESAMPLERS: dict[str, Resampler] = {"multinomial": multinomial_resample, "systematic": systematic_resample}


def effective_sample_size(weights: torch.Tensor) -> float:
    """Kish's effective sample size ``1 / Σ w_i²`` of normalised weights (N,)."""
    w = weights / weights.sum()
    return float(1.0 / (w * w).sum())
