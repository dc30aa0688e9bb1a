"""Empty-space skipping for the grid field's no-gradient renderer.

A ray is a lattice of samples ``p_k = start + k · step`` (k = 0 … count-1) in vertex coordinates
(vertex (i, j, l) of the grid sits at (i, j, l)); a sample counts when the vertex nearest to it is
occupied. The marcher never looks at most empty samples: a Chebyshev distance grid ``D`` (in
vertices, from each vertex to the nearest occupied one) proves a stretch of samples empty, and the
ray jumps over it. Bound: if sample p rounds to vertex a with ``D[a] = d``, sample
``q = p + j · step`` rounds to a vertex b with ``|b - a|∞ ≤ 1 + j · |step|∞``, so every
``j < (d - 1) / |step|∞`` is empty. Where the bound allows only short jumps (on or near occupied
space) the ray tests its next ``block`` samples one by one instead and shades and composites the
occupied ones (transmittance carried across blocks); it stops when its transmittance falls below the
termination threshold. The samples composited are exactly those a dense scan of the lattice would
keep, so the result equals dense sampling up to float rounding and the termination threshold.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch.profiler import record_function

Shader = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""positions (N, 3) in vertex coordinates -> optical depth σ·δ (N,), channels to composite (N, C)."""

JUMP_MARGIN = 1e-3
"""Vertices of slack in the skip bound against float rounding."""
SKIP_DISTANCE_CAP = 16
"""Largest Chebyshev distance (vertices) a skip table stores: longer jumps gain little inside the occupied box."""
BLOCK_SAMPLES = 24
"""Samples a ray tests (and shades where occupied) per round once it is near occupied space."""
MIN_JUMP = 4
"""Shortest jump, in samples, worth a round of skipping (shorter ones are left to the next block)."""
SKIP_STRAGGLERS = 32
"""A skip loop stops when fewer than 1/SKIP_STRAGGLERS of the rays it started with still jump."""


def chebyshev_distance(occupancy: torch.Tensor, cap: int) -> torch.Tensor:
    """(Z, Y, X) uint8: L∞ distance in vertices from each vertex to the nearest occupied one, at most ``cap``.

    Args:
        occupancy: (Z, Y, X) bool.
        cap: largest distance stored (1 … 255); farther vertices (and all, for an empty grid) get ``cap``.
    """
    if occupancy.dim() != 3 or occupancy.dtype != torch.bool:
        raise ValueError(f"occupancy must be a (Z, Y, X) bool tensor, got {tuple(occupancy.shape)} {occupancy.dtype}")
    if not 1 <= cap <= 255:
        raise ValueError(f"cap must be in 1..255, got {cap}")
    reach = occupancy
    distance = torch.zeros(occupancy.shape, dtype=torch.uint8, device=occupancy.device)
    for _ in range(cap):
        distance += ~reach
        for axis in range(3):  # one vertex of L∞ dilation, separably along z, y and x
            length = reach.shape[axis]
            grown = reach.clone()
            grown.narrow(axis, 0, length - 1).logical_or_(reach.narrow(axis, 1, length - 1))
            grown.narrow(axis, 1, length - 1).logical_or_(reach.narrow(axis, 0, length - 1))
            reach = grown
    return distance


class SkipTable:
    """Per-vertex ``D - 1`` as int8 (-1 at occupied vertices), padded by one vertex of "far" on every
    side, for lookups by position. Int8 keeps the table small: random lookups into a 128³ float
    table measured several times slower on the 2-core development machine."""

    def __init__(self, distance: torch.Tensor) -> None:
        """``distance``: (Z, Y, X) uint8 from :func:`chebyshev_distance` (at most 128)."""
        z, y, x = distance.shape
        cap = int(distance.max()) if distance.numel() else 1
        if cap > 128:
            raise ValueError(f"distances up to 128 fit the int8 skip table, got {cap}")
        padded = torch.full((z + 2, y + 2, x + 2), cap - 1, dtype=torch.int8, device=distance.device)
        padded[1:-1, 1:-1, 1:-1] = (distance.to(torch.int16) - 1).to(torch.int8)
        self.gap = padded.reshape(-1)
        self.row, self.plane = x + 2, (x + 2) * (y + 2)

    def __call__(self, shifted: torch.Tensor) -> torch.Tensor:
        """Gap ``D - 1`` (...) int8 at positions (..., 3) given as vertex coordinates + 1.5 (truncation then
        names the padded index of the nearest vertex); positions must lie within half a vertex of the grid."""
        index = shifted.long()
        return self.gap.take(index[..., 0] + index[..., 1] * self.row + index[..., 2] * self.plane)


# Columns of the packed per-ray table the marcher compacts in one gather.
_START, _STEP, _INVERSE_REACH, _COUNT = slice(0, 3), slice(3, 6), 6, 7


def _skip_empty(table: SkipTable, rays_table: torch.Tensor, index: torch.Tensor, rays: torch.Tensor, min_jump: int) -> None:
    """Advance ``index[rays]`` in place over samples proven empty, while each jump spans at least ``min_jump`` samples.

    A ray stops on an occupied sample, near one (where the bound proves only short jumps: the
    block that follows tests its samples one by one), or past its last sample. The loop ends
    early once only stragglers (1/``SKIP_STRAGGLERS`` of the rays) are left: they continue in the
    block, which costs less than many rounds of a handful of rays.
    """
    rows, at = rays_table[rays], index[rays]
    straggle = len(rays) // SKIP_STRAGGLERS
    while len(rays) > straggle:
        gap = table(torch.addcmul(rows[:, _START], at[:, None], rows[:, _STEP]))
        jump = torch.ceil((gap - JUMP_MARGIN) * rows[:, _INVERSE_REACH])
        far = jump >= min_jump
        at = torch.where(far, at + jump, at)
        index[rays] = at
        going = (far & (at < rows[:, _COUNT])).nonzero(as_tuple=True)[0]
        rays, rows, at = rays[going], rows[going], at[going]


def march(
    start: torch.Tensor,
    step: torch.Tensor,
    counts: torch.Tensor,
    table: SkipTable,
    shade: Shader,
    channels: int,
    termination_transmittance: float,
    block: int = BLOCK_SAMPLES,
    min_jump: int = MIN_JUMP,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite the occupied samples of every ray front to back, skipping proven-empty stretches.

    Quadrature as in :mod:`locnerf.render.volume`: ``w_k = T_k (1 - exp(-σ_k δ))`` with the
    transmittance ``T_k`` carried from block to block in log space.

    Args:
        start: (R, 3) vertex coordinates of sample 0 of each ray.
        step: (R, 3) vertex-coordinate increment from one sample to the next.
        counts: (R,) samples on each ray (every sample must lie in the grid).
        table: the skip table of the occupancy (:class:`SkipTable` of :func:`chebyshev_distance`).
        shade: optical depth and channels of positions, see :data:`Shader` (the marcher scales the
            channels it gets in place).
        channels: C, the width of what ``shade`` returns.
        termination_transmittance: rays stop once their transmittance falls below this.
        block: samples tested and shaded per ray per round once a ray is near an occupied sample.
        min_jump: shortest jump (in samples) worth a skip round; shorter ones are left to the block.
    Returns:
        composited channels (R, C) (Σ w_k c_k) and log transmittance (R,) left after the last sample.
    """
    if block < 1 or min_jump < 1:
        raise ValueError(f"block and min_jump must be positive numbers of samples, got {block} and {min_jump}")
    rays, device, dtype = start.shape[0], start.device, start.dtype
    reach = step.abs().amax(dim=-1, keepdim=True).clamp_min(1e-12)
    rays_table = torch.cat((start + 1.5, step, 1.0 / reach, counts[:, None].to(dtype)), dim=-1)
    composited = torch.zeros(rays, channels, device=device, dtype=dtype)
    log_transmittance = torch.zeros(rays, device=device, dtype=dtype)
    index = torch.zeros(rays, device=device, dtype=dtype)  # next sample to look at (integral floats)
    offsets = torch.arange(block, device=device, dtype=dtype)
    stop_log = math.log(termination_transmittance)
    active = (counts > 0).nonzero(as_tuple=True)[0]
    while len(active):
        with record_function("march: empty-space skip"):
            _skip_empty(table, rays_table, index, active, min_jump)
        with record_function("march: block samples, occupancy test"):
            rows, at = rays_table[active], index[active]
            inside = (at < rows[:, _COUNT]).nonzero(as_tuple=True)[0]
            active, rows, at = active[inside], rows[inside], at[inside]
            if not len(active):
                break
            sample = at[:, None] + offsets  # (A, B)
            last = rows[:, _COUNT, None] - 1.0
            shifted = torch.addcmul(rows[:, None, _START], torch.minimum(sample, last)[..., None], rows[:, None, _STEP])  # (A, B, 3)
            local, column = ((sample <= last) & (table(shifted) < 0)).nonzero(as_tuple=True)
        with record_function("march: gather, shade"):
            depth_values, values = shade(shifted[local, column] - 1.5)
        with record_function("march: composite, terminate"):
            depth = torch.zeros(len(active), block, device=device, dtype=dtype).index_put_((local, column), depth_values)
            log_before = log_transmittance[active, None] - (torch.cumsum(depth, dim=-1) - depth)  # log T_k
            weights = torch.exp(log_before[local, column]) * -torch.expm1(-depth_values)
            composited.index_add_(0, active[local], values.mul_(weights[:, None]))
            log_after = log_before[:, -1] - depth[:, -1]
            at = at + block
            log_transmittance[active] = log_after
            index[active] = at
            active = active[((log_after > stop_log) & (at < rows[:, _COUNT])).nonzero(as_tuple=True)[0]]
    return composited, log_transmittance
