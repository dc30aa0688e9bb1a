"""The particle set: poses, log-weights and stable identities."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from locnerf.geometry.validation import validate_poses


@dataclass
class ParticleSet:
    """N weighted pose hypotheses.

    Attributes:
        poses: (N, 4, 4) camera-to-world poses ``T_world_cam`` in map units.
        log_weights: (N,) normalised log-weights (``logsumexp == 0``).
        ids: (N,) int64 stable identities; prediction keeps them, resampling issues new ones, and
            convergence protection new ones for the particles it re-draws.
        parent_ids: (N,) int64 identity of each particle's parent at the last resampling, -1 for
            particles no update has weighed yet: drawn at initialisation, injected by recovery or
            re-drawn by convergence protection since.
        generation: incremented by every resampling and every convergence protection (the
            localizer's lineage records each generation's parents).
    """

    poses: torch.Tensor
    log_weights: torch.Tensor
    ids: torch.Tensor
    parent_ids: torch.Tensor
    generation: int = 0

    def __post_init__(self) -> None:
        count = self.poses.shape[0] if self.poses.ndim == 3 else -1
        if count < 1:
            raise ValueError(f"particle poses: expected shape (N>=1, 4, 4), got {tuple(self.poses.shape)}")
        for name in ("log_weights", "ids", "parent_ids"):
            shape = tuple(getattr(self, name).shape)
            if shape != (count,):
                raise ValueError(f"particle {name}: expected shape ({count},), got {shape}")

    @property
    def count(self) -> int:
        return int(self.poses.shape[0])

    @property
    def weights(self) -> torch.Tensor:
        """(N,) normalised weights."""
        return torch.exp(self.log_weights)

    @property
    def positions(self) -> torch.Tensor:
        """(N, 3) camera positions."""
        return self.poses[:, :3, 3]

    @classmethod
    def from_poses(cls, poses: torch.Tensor, first_id: int = 0, generation: int = 0) -> ParticleSet:
        """Equally weighted particles with ids ``first_id .. first_id + N - 1`` and no parents."""
        validate_poses(poses, name="particle poses")
        if poses.ndim != 3:
            raise ValueError(f"particle poses: expected shape (N, 4, 4), got {tuple(poses.shape)}")
        count = poses.shape[0]
        log_weights = torch.full((count,), -torch.log(torch.tensor(float(count))).item(), dtype=poses.dtype, device=poses.device)
        ids = torch.arange(first_id, first_id + count, dtype=torch.int64, device=poses.device)
        parents = torch.full((count,), -1, dtype=torch.int64, device=poses.device)
        return cls(poses=poses, log_weights=log_weights, ids=ids, parent_ids=parents, generation=generation)


def normalise_log_weights(log_weights: torch.Tensor) -> torch.Tensor:
    """Shift (N,) log-weights so that their exponentials sum to one."""
    return log_weights - torch.logsumexp(log_weights, dim=0)


def weighted_position_spread(positions: torch.Tensor, weights: torch.Tensor) -> float:
    """Largest per-axis weighted standard deviation of positions (N, 3) with weights (N,).

    This is the spread that Algorithm 1's annealing compares with α_refine / α_super_refine.
    """
    w = weights / weights.sum()
    mean = (w[:, None] * positions).sum(dim=0)
    variance = (w[:, None] * (positions - mean) ** 2).sum(dim=0)
    return float(torch.sqrt(variance).max())
