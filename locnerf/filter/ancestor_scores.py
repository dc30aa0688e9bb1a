"""An update's log-likelihoods, computed on a snapshot, turned into each current particle's: failed
computations made impossible, each particle given its snapshot ancestor's value, and the particles
drawn since the snapshot given a stand-in (design section 3); and the best of them that recovery watches."""

from __future__ import annotations

import logging

import torch

from locnerf.filter.lineage import NO_ANCESTOR, lookup
from locnerf.geometry.averaging import chordal_rotation_mean, tangent_residuals
from locnerf.geometry.se3 import make_pose

logger = logging.getLogger(__name__)

RIDGE = 1e-9
"""Added to the scored cloud's tangent covariance, times its largest variance (plus 1e-12 absolute), before whitening: a
cloud flat along an axis (all scored particles copies of one) stays invertible."""


def failures_as_impossible(log_likelihoods: torch.Tensor) -> torch.Tensor:
    """(K,) log-likelihoods with NaN and +inf (failed computations) made −inf, like a failed render; −inf stays −inf."""
    failed = torch.isnan(log_likelihoods) | (log_likelihoods == torch.inf)
    return log_likelihoods.masked_fill(failed, -torch.inf)


def ancestor_log_likelihoods(ids: torch.Tensor, log_likelihoods: torch.Tensor, ancestors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Each current particle's log-likelihood (N,) float64: its ancestor's, from the snapshot's ``ids`` (K,) and
    ``log_likelihoods`` (K,); particles with no ancestor in the snapshot (injected or re-drawn since, ``ancestors``
    (N,) :data:`NO_ANCESTOR`) get the median of the finite ones (−inf when there is none).

    Returns:
        The log-likelihoods (N,) and which particles got the median stand-in (N,) bool.
    """
    order = torch.argsort(ids)
    per_particle = lookup(ids[order], log_likelihoods[order], ancestors, float("nan"))
    finite = torch.isfinite(log_likelihoods)
    stand_in = log_likelihoods[finite].median() if bool(finite.any()) else -torch.inf
    unscored = torch.isnan(per_particle) | (ancestors == NO_ANCESTOR)
    per_particle[unscored] = stand_in
    return per_particle, unscored


def borrowed_log_likelihoods(per_particle: torch.Tensor, unscored: torch.Tensor, poses: torch.Tensor, reach: float) -> torch.Tensor:
    """Unscored particles inside the scored cloud take the log-likelihood of their nearest scored neighbour.

    A particle drawn after the snapshot (a refining draw of recovery, a re-draw of convergence protection) was
    not measured by this update. Where it lies among measured particles, the nearest one's value estimates its
    own far better than the median does (with a sharp likelihood the median is nats under the best, so the draw
    would die at this resampling before any update had weighed it). Each pose is read as ``(Log(R̄ᵀR), R̄ᵀt)``
    about the scored particles' chordal mean rotation R̄, and distances are Mahalanobis distances under the
    scored particles' covariance of those: "near" follows the cloud's own scale in each of the six axes. A
    particle farther than ``reach`` from their mean lies outside the measured support (a recovery draw around
    a far keyframe) and keeps the median.

    Args:
        per_particle: (N,) float64 log-likelihoods from :func:`ancestor_log_likelihoods` (not changed).
        unscored: (N,) bool, the particles that got the median stand-in.
        poses: (N, 4, 4) the particles' current poses (all moved alike since the snapshot).
        reach: Mahalanobis radius of the measured support (0: every unscored particle keeps the median).
    Returns:
        (N,) float64 log-likelihoods.
    """
    unscored = unscored.cpu()
    scored = ~unscored & torch.isfinite(per_particle)
    if reach <= 0 or not bool(unscored.any()) or int(scored.sum()) < 2:
        return per_particle
    poses = poses.detach().double().cpu()
    centre = make_pose(chordal_rotation_mean(poses[scored, :3, :3]), poses[scored, :3, 3].mean(dim=0))
    residuals = tangent_residuals(poses, centre)
    residuals = residuals - residuals[scored].mean(dim=0)  # the chordal mean is not the rotations' residual mean
    covariance = torch.cov(residuals[scored].T)
    covariance = covariance + torch.eye(6, dtype=torch.float64) * (RIDGE * float(torch.diagonal(covariance).max()) + 1e-12)
    whitened = torch.linalg.solve_triangular(torch.linalg.cholesky(covariance), residuals.T, upper=False).T
    candidates = torch.nonzero(unscored).squeeze(1)
    candidates = candidates[torch.linalg.vector_norm(whitened[candidates], dim=-1) <= reach]
    if candidates.numel() == 0:
        return per_particle
    scored_index = torch.nonzero(scored).squeeze(1)
    # Whitened coordinates are of order one: float32 orders the distances (and runs at twice float64's speed).
    nearest = torch.cdist(whitened[candidates].float(), whitened[scored_index].float()).argmin(dim=1)
    borrowed = per_particle.clone()
    borrowed[candidates] = per_particle[scored_index[nearest]]
    logger.debug("%d of %d particles drawn since the snapshot took a measured neighbour's log-likelihood", candidates.numel(), int(unscored.sum()))
    return borrowed


def current_log_likelihoods(
    ids: torch.Tensor, log_likelihoods: torch.Tensor, ancestors: torch.Tensor, poses: torch.Tensor, borrow_reach: float
) -> torch.Tensor:
    """Each current particle's log-likelihood (N,) float64 from a result on a snapshot: failures made −inf
    (:func:`failures_as_impossible`), each particle its ancestor's value (:func:`ancestor_log_likelihoods`), and
    particles drawn since inside the measured cloud their nearest measured neighbour's (:func:`borrowed_log_likelihoods`).

    Args:
        ids: (K,) the snapshot's particle ids; log_likelihoods: (K,) the result; ancestors: (N,) each current
            particle's ancestor id in the snapshot; poses: (N, 4, 4) the current poses; borrow_reach: see
            :func:`borrowed_log_likelihoods`.
    """
    per_particle, unscored = ancestor_log_likelihoods(ids, failures_as_impossible(log_likelihoods), ancestors)
    return borrowed_log_likelihoods(per_particle, unscored, poses, borrow_reach)


def best_weighed_log_likelihood(parent_ids: torch.Tensor, per_particle: torch.Tensor) -> float:
    """Largest log-likelihood (N,) -> float among the particles that descend from weighed ones (``parent_ids`` (N,)).

    Recovery compares this over time rather than the mean likelihood of augmented MCL: with
    eq. 5's sharp likelihood the mean mostly measures how tight the cluster is (a looser cluster
    has fewer particles near the peak), so annealing or the injections themselves would keep
    triggering injections after the filter has recovered. Particles injected at the last
    resampling or re-drawn by convergence protection since (``parent_ids`` :data:`NO_ANCESTOR`)
    are left out for the same reason.
    """
    survivors = (parent_ids != NO_ANCESTOR).cpu()
    return float(per_particle[survivors].max() if bool(survivors.any()) else per_particle.max())
