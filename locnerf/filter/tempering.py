"""Adaptive tempering: weigh a spread cloud by a fraction of the evidence, so that it cannot collapse at once.

A sharp likelihood (eq. 5's γ, and the depth term's γ_d = 16 of the RGB-D configurations) on a cloud
spread over a room gives nearly all the weight to the few particles that happen to lie nearest some
match after one update; resampling then copies those few, and if they sat in a wrong basin, no particle
is left in the right one (particle deprivation). Sequential Monte Carlo samplers avoid this by
*tempering* (Del Moral, Doucet & Jasra 2006; the adaptive choice of the exponent: Jasra et al. 2011):
each step multiplies the weights by ``L^β`` with the largest β ∈ (0, 1] that keeps the effective
sample size at or above a fraction ρ of the particles,

    β* = max { β ∈ (0, 1] : ESS(w · L^β) ≥ ρ N },

found by bisection (ESS falls as β grows). The rest of the evidence is not lost: a single-image search
re-weighs the same image on every update, and a tracking filter sees the next image, so a tempered
update only slows the collapse to the rate the cloud can follow, keeping the other basins alive
until the evidence tells them apart.
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.filter.particles import normalise_log_weights
from locnerf.filter.resampling import effective_sample_size

__all__ = ["TemperingConfig", "tempered", "tempering_exponent"]

_BISECTION_STEPS = 30


class TemperingConfig(BaseModel):
    """When and how far an update is tempered (off unless ``min_ess_fraction`` is set)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    min_ess_fraction: float | None = Field(
        None,
        gt=0,
        lt=1,
        description="ρ: an update keeps the effective sample size at or above ρ × the particle count by "
        "raising its likelihoods to a power β ≤ 1 (None: every update at full strength).",
    )
    coarse_only: bool = Field(True, description="Temper only while the annealing stage is COARSE (the cloud is spread).")


def tempered(log_likelihoods: torch.Tensor, beta: float) -> torch.Tensor:
    """``β · log L`` of (N,) log-likelihoods, −inf kept (0 · −inf would be NaN)."""
    return torch.where(torch.isfinite(log_likelihoods), beta * log_likelihoods, log_likelihoods)


def _ess_fraction(log_weights: torch.Tensor) -> float:
    """Effective sample size over N of log-weights (N,) (not necessarily normalised)."""
    return effective_sample_size(torch.exp(normalise_log_weights(log_weights))) / log_weights.numel()


def tempering_exponent(log_weights: torch.Tensor, log_likelihoods: torch.Tensor, min_ess_fraction: float) -> float:
    """β* of the module docstring.

    Args:
        log_weights: (N,) current normalised log-weights (float64; −inf allowed).
        log_likelihoods: (N,) the update's log-likelihoods (float64; −inf allowed, no NaN).
        min_ess_fraction: ρ in (0, 1).
    Returns:
        1.0 when the full update keeps ESS ≥ ρN (or when the weights are already below it: tempering
        cannot raise the ESS above what the weights alone have), else the largest β found by bisection
        with ESS ≥ ρN (at least 2⁻³⁰).
    """
    if log_weights.shape != log_likelihoods.shape or log_weights.ndim != 1:
        raise ValueError(f"log_weights {tuple(log_weights.shape)} and log_likelihoods {tuple(log_likelihoods.shape)}: expected two (N,) tensors")
    if not 0.0 < min_ess_fraction < 1.0:
        raise ValueError(f"min_ess_fraction={min_ess_fraction}: expected a fraction in (0, 1)")
    finite = torch.isfinite(log_likelihoods)
    if not bool(finite.any()):
        return 1.0
    # Shift so the largest finite likelihood is 0: β·L then never overflows, and −inf stays −inf.
    shifted = log_likelihoods - log_likelihoods[finite].max()

    def ess(beta: float) -> float:
        return _ess_fraction(log_weights + tempered(shifted, beta))

    if ess(1.0) >= min_ess_fraction or ess(0.0) < min_ess_fraction:
        return 1.0
    low, high = 0.0, 1.0
    for _ in range(_BISECTION_STEPS):
        middle = 0.5 * (low + high)
        if ess(middle) >= min_ess_fraction:
            low = middle
        else:
            high = middle
    return max(low, 2.0**-_BISECTION_STEPS)
