"""An update's log-likelihoods, computed on a snapshot, turned into each current particle's: failed
computations made impossible, each particle given its snapshot ancestor's value (design section 3)."""

from __future__ import annotations

import torch

from locnerf.filter.lineage import NO_ANCESTOR, lookup


def failures_as_impossible(log_likelihoods: torch.Tensor) -> torch.Tensor:
    """(K,) log-likelihoods with NaN and +inf (failed computations) made −inf, like a failed render; −inf stays −inf."""
    failed = torch.isnan(log_likelihoods) | (log_likelihoods == torch.inf)
    return log_likelihoods.masked_fill(failed, -torch.inf)


def ancestor_log_likelihoods(ids: torch.Tensor, log_likelihoods: torch.Tensor, ancestors: torch.Tensor) -> torch.Tensor:
    """Each current particle's log-likelihood (N,) float64: its ancestor's, from the snapshot's ``ids`` (K,) and
    ``log_likelihoods`` (K,); particles with no ancestor in the snapshot (injected or re-drawn since, ``ancestors``
    (N,) :data:`NO_ANCESTOR`) get the median of the finite ones (−inf when there is none)."""
    order = torch.argsort(ids)
    per_particle = lookup(ids[order], log_likelihoods[order], ancestors, float("nan"))
    finite = torch.isfinite(log_likelihoods)
    stand_in = log_likelihoods[finite].median() if bool(finite.any()) else -torch.inf
    per_particle[torch.isnan(per_particle) | (ancestors == NO_ANCESTOR)] = stand_in
    return per_particle
