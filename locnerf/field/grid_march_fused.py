"""The grid field's skip marcher as one compiled loop per ray (numba): the CPU path of the no-gradient render.

:func:`locnerf.field.grid_march.march` runs the march as batched torch ops (a skip round, then a
block of ``BLOCK_SAMPLES`` samples, for all rays at once), which keeps a GPU busy but costs a CPU
hundreds of small ops and their temporaries per render (docs/PERFORMANCE.md, "Where the update step's
time goes"). Here each ray is one loop, compiled by numba, that does the same work in registers:

* the same lattice ``start + k · step`` (vertex coordinates) and the same samples: sample k is
  shaded when its nearest vertex is occupied (the skip table's gap ``D - 1 < 0``); otherwise the
  Chebyshev bound of :mod:`locnerf.field.grid_march` proves the next ``ceil((D - 1) / |step|∞)``
  samples empty and the loop jumps over them;
* the same shading as ``GridField._shade``: trilinear interpolation of the grid's raw channels
  (positions clamped to the grid), optical depth ``softplus(raw σ + shift) · scale``, sigmoid of the
  diffuse colour, the view features as they are (and the vertex position, for surface renders);
* the same quadrature ``w_k = T_k (1 - exp(-σ_k δ))``, accumulated in float64;
* termination per sample, as soon as the transmittance falls below the threshold (the torch marcher
  stops at the end of a block of samples, so it composites up to ``BLOCK_SAMPLES - 1`` samples more,
  whose weights sum to less than the threshold): the two agree to about the termination
  transmittance times the channels' magnitude (tests/field/test_grid_march_fused.py).

Rays are split over ``torch.get_num_threads()`` threads (numba's ``prange``); with one thread
(the services' setting) the serial variant runs, which needs no threading layer and may be called
from any Python thread. Compiled code is cached on disk (numba's ``cache=True``) after the first call.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from locnerf.field.grid_march import JUMP_MARGIN, SkipTable

_SOFTPLUS_THRESHOLD = 20.0  # torch.nn.functional.softplus returns x above this
_CHUNKS_PER_THREAD = 8  # rays are split in chunks, each with its own scratch row


@numba.njit(cache=True, nogil=True, inline="always")
def _march_ray(
    ray: int,
    start: np.ndarray,
    step: np.ndarray,
    counts: np.ndarray,
    gap: np.ndarray,
    row: int,
    plane: int,
    grid: np.ndarray,
    cells: np.ndarray,
    shift: float,
    scale: float,
    stop: float,
    with_position: bool,
    values: np.ndarray,
    out: np.ndarray,
    log_transmittance: np.ndarray,
) -> None:
    """March ray ``ray``: composite into ``out[ray]`` (zeroed here) and store its log transmittance; ``values`` is scratch (C,)."""
    channels = grid.shape[1]
    rx, ry = cells[0] + 1, cells[1] + 1
    sx, sy, sz = float(start[ray, 0]), float(start[ray, 1]), float(start[ray, 2])
    dx, dy, dz = float(step[ray, 0]), float(step[ray, 1]), float(step[ray, 2])
    inverse_reach = 1.0 / max(abs(dx), abs(dy), abs(dz), 1e-12)
    width = out.shape[1]
    for c in range(width):
        out[ray, c] = 0.0
    log_t, transmittance = 0.0, 1.0
    count = counts[ray]
    k = 0
    while k < count:
        px, py, pz = sx + k * dx, sy + k * dy, sz + k * dz
        # nearest vertex, +1 for the skip table's padding (positions lie within half a vertex of the grid)
        nx = min(max(int(px + 1.5), 0), cells[0] + 2)
        ny = min(max(int(py + 1.5), 0), cells[1] + 2)
        nz = min(max(int(pz + 1.5), 0), cells[2] + 2)
        distance_gap = gap[nx + ny * row + nz * plane]
        if distance_gap >= 0:
            k += max(int(math.ceil((distance_gap - JUMP_MARGIN) * inverse_reach)), 1)
            continue
        # trilinear weights of the 8 vertices around the clamped position
        qx = min(max(px, 0.0), float(cells[0]))
        qy = min(max(py, 0.0), float(cells[1]))
        qz = min(max(pz, 0.0), float(cells[2]))
        cx = min(int(math.floor(qx)), cells[0] - 1)
        cy = min(int(math.floor(qy)), cells[1] - 1)
        cz = min(int(math.floor(qz)), cells[2] - 1)
        fx, fy, fz = qx - cx, qy - cy, qz - cz
        gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
        base = cx + cy * rx + cz * rx * ry
        for c in range(channels):
            values[c] = 0.0
        for corner in range(8):
            ox, oy, oz = corner & 1, (corner >> 1) & 1, corner >> 2
            weight = (fx if ox else gx) * (fy if oy else gy) * (fz if oz else gz)
            vertex = base + ox + oy * rx + oz * rx * ry
            for c in range(channels):
                values[c] += weight * grid[vertex, c]
        # optical depth σ·δ = softplus(raw) · scale; the step's transmittance exp(-σ·δ) is (1 + e^raw)^-scale
        raw = values[0] + shift
        if raw > _SOFTPLUS_THRESHOLD:
            optical = raw * scale
            through = math.exp(-optical)
        elif scale == 1.0:
            grow = 1.0 + math.exp(raw)
            optical = math.log(grow)
            through = 1.0 / grow
        else:
            optical = math.log1p(math.exp(raw)) * scale
            through = math.exp(-optical)
        weight = transmittance * (1.0 - through)
        for c in range(3):
            out[ray, c] += weight / (1.0 + math.exp(-values[1 + c]))
        for c in range(4, channels):
            out[ray, c - 1] += weight * values[c]
        if with_position:
            out[ray, channels - 1] += weight * px
            out[ray, channels] += weight * py
            out[ray, channels + 1] += weight * pz
        log_t -= optical
        transmittance *= through
        k += 1
        if transmittance < stop:
            break
    log_transmittance[ray] = log_t


@numba.njit(cache=True, nogil=True)
def _march_serial(start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, out, log_transmittance) -> None:  # noqa: ANN001
    values = np.empty(grid.shape[1], dtype=np.float64)
    for ray in range(start.shape[0]):
        _march_ray(ray, start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, values, out, log_transmittance)


@numba.njit(cache=True, nogil=True, parallel=True)
def _march_parallel(start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, out, log_transmittance, chunks) -> None:  # noqa: ANN001
    rays = start.shape[0]
    for chunk in numba.prange(chunks):
        values = np.empty(grid.shape[1], dtype=np.float64)
        for ray in range(chunk * rays // chunks, (chunk + 1) * rays // chunks):
            _march_ray(ray, start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, values, out, log_transmittance)


def fused_march(
    start: torch.Tensor,
    step: torch.Tensor,
    counts: torch.Tensor,
    table: SkipTable,
    grid: torch.Tensor,
    resolution: tuple[int, int, int],
    shift: float,
    scale: float,
    termination_transmittance: float,
    with_position: bool,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite every ray's occupied samples front to back on the CPU (module docstring).

    Args:
        start: (R, 3) vertex coordinates of sample 0 of each ray.
        step: (R, 3) vertex-coordinate increment from one sample to the next.
        counts: (R,) samples on each ray (every sample within half a vertex of the grid).
        table: the skip table of the occupancy (:class:`locnerf.field.grid_march.SkipTable`).
        grid: (V, C) raw channels (σ, 3 diffuse, C - 4 features), vertex-major (x fastest); float32 or float16.
        resolution: (Rx, Ry, Rz) vertices per axis.
        shift: added to raw σ before softplus; scale: multiplies the softplus (σ·δ of one render step).
        termination_transmittance: a ray stops once its transmittance falls below this.
        with_position: also composite the sample positions (vertex coordinates) as three more channels.
    Returns:
        composited (R, C - 1 [+ 3]) float32 (Σ w_k c_k) and log transmittance (R,) float32 after the last sample composited.
    """
    if start.device.type != "cpu":
        raise ValueError(f"fused_march runs on the CPU; got tensors on {start.device}")
    rays, channels = start.shape[0], grid.shape[1]
    out = np.empty((rays, channels - 1 + (3 if with_position else 0)), dtype=np.float32)
    log_transmittance = np.empty(rays, dtype=np.float32)
    arguments = (
        np.ascontiguousarray(start.detach().numpy(), dtype=np.float32),
        np.ascontiguousarray(step.detach().numpy(), dtype=np.float32),
        np.ascontiguousarray(counts.numpy(), dtype=np.int64),
        table.gap.numpy(),
        table.row,
        table.plane,
        grid.detach().numpy(),
        np.array([r - 1 for r in resolution], dtype=np.int64),
        float(shift),
        float(scale),
        float(termination_transmittance),
        bool(with_position),
        out,
        log_transmittance,
    )
    threads = torch.get_num_threads()
    if threads > 1 and rays > 1:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        _march_parallel(*arguments, min(rays, threads * _CHUNKS_PER_THREAD))
    else:
        _march_serial(*arguments)
    return torch.from_numpy(out), torch.from_numpy(log_transmittance)
