"""Ancestry of particles across resampling generations, for merging delayed updates.

An update is computed on a snapshot of generation g. By the time its result arrives the filter may
have resampled (g+1, g+2, ...). Each current particle must receive the log-likelihood of its
ancestor in generation g. The lineage keeps, for the last few generations, the map from each
particle id to its parent id, and walks current ids back to generation g (vectorised lookups).
"""

from __future__ import annotations

from collections import deque

import torch

NO_ANCESTOR = -1


def lookup(keys_sorted: torch.Tensor, values: torch.Tensor, queries: torch.Tensor, missing: int | float) -> torch.Tensor:
    """``values[k]`` for each query equal to ``keys_sorted[k]``, or ``missing`` where absent.

    Args:
        keys_sorted: (K,) ascending unique keys; values: (K, ...) aligned; queries: (Q,).
    Returns:
        (Q, ...) gathered values.
    """
    if keys_sorted.numel() == 0:
        return torch.full((queries.shape[0], *values.shape[1:]), missing, dtype=values.dtype)
    position = torch.searchsorted(keys_sorted, queries).clamp_(max=keys_sorted.numel() - 1)
    found = keys_sorted[position] == queries
    gathered = values[position].clone()
    gathered[~found] = missing
    return gathered


class Lineage:
    """Parent links of the most recent generations."""

    def __init__(self, depth: int = 64) -> None:
        # Entries (generation, child ids sorted, their parent ids), newest last.
        self._generations: deque[tuple[int, torch.Tensor, torch.Tensor]] = deque(maxlen=depth)

    def clear(self) -> None:
        self._generations.clear()

    def record(self, generation: int, child_ids: torch.Tensor, parent_ids: torch.Tensor) -> None:
        """Remember which parent each child of ``generation`` came from."""
        order = torch.argsort(child_ids)
        self._generations.append((generation, child_ids[order].cpu(), parent_ids[order].cpu()))

    def oldest_reachable(self, current_generation: int) -> int:
        """The oldest generation whose descendants can still be traced."""
        if not self._generations:
            return current_generation
        return self._generations[0][0] - 1

    def ancestors(self, ids: torch.Tensor, current_generation: int, target_generation: int) -> torch.Tensor:
        """Ids in ``target_generation`` of the ancestors of ``ids`` (current generation).

        Particles that descend from none in the target generation (injected by recovery, re-drawn by
        convergence protection) map to :data:`NO_ANCESTOR`.

        Raises:
            ValueError: if the target is newer than the current generation or no longer traceable.
        """
        if target_generation > current_generation:
            raise ValueError(f"generation {target_generation}: newer than the current generation {current_generation}")
        if target_generation < self.oldest_reachable(current_generation):
            raise ValueError(f"generation {target_generation}: older than the lineage kept")
        result = ids.cpu().clone()
        for generation, child_ids, parent_ids in reversed(self._generations):
            if generation <= target_generation:
                break
            if generation > current_generation:
                continue
            traced = result != NO_ANCESTOR
            result[traced] = lookup(child_ids, parent_ids, result[traced], NO_ANCESTOR)
        return result
