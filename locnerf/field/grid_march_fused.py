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

Memory order: a shaded sample reads 8 rows of the grid (48 bytes each on a 12-channel map), and a
grid of 100 MB does not stay in cache, so rays taken in the caller's order miss it at almost every
sample. A first pass finds each ray's first occupied sample (it is where the second pass starts) and
keys the ray by the Morton code of the brick around it; the rays are then marched in key order (a
counting sort), so that rays that meet the same part of the scene read the same rows one after the
other. Each ray's result does not depend on the order.

Rays are split over ``torch.get_num_threads()`` threads (numba's ``prange``; one parallel render at
a time per process); with one thread (the services' setting) the serial variant runs, which needs no
threading layer and may run in several Python threads at once. Compiled code is cached on disk (numba's ``cache=True``) after the first call.
"""

from __future__ import annotations

import math
import threading

import numba
import numpy as np
import torch
from torch.profiler import record_function

from locnerf.field.grid_march import JUMP_MARGIN, SkipTable, chebyshev_distance

_SOFTPLUS_THRESHOLD = 20.0  # torch.nn.functional.softplus returns x above this
_CHUNKS_PER_THREAD = 8  # rays are split in chunks, each with its own scratch row
_PARALLEL_LAUNCH = threading.Lock()
"""Parallel renders of one process take turns: numba's workqueue threading layer (where OpenMP and TBB are missing) aborts on concurrent launches."""
_COMPILED = False  # compile_ahead has run in this process
_KEY_BITS = 6  # bits per axis of the brick coordinates that order the rays (2**18 buckets)


@numba.njit(cache=True, nogil=True, inline="always")
def _nearest_gap(px: float, py: float, pz: float, gap: np.ndarray, row: int, plane: int, cells: np.ndarray) -> tuple[int, int, int, int]:
    """The skip table's ``D - 1`` at the vertex nearest to (px, py, pz) and that vertex's padded (x, y, z) index."""
    nx = min(max(int(px + 1.5), 0), cells[0] + 2)
    ny = min(max(int(py + 1.5), 0), cells[1] + 2)
    nz = min(max(int(pz + 1.5), 0), cells[2] + 2)
    return gap[nx + ny * row + nz * plane], nx, ny, nz


@numba.njit(cache=True, nogil=True)
def _first_occupied(
    ray: int, start: np.ndarray, step: np.ndarray, counts: np.ndarray, gap: np.ndarray, row: int, plane: int, cells: np.ndarray, brick: int
) -> tuple[int, int]:
    """Index of ray ``ray``'s first occupied sample (``counts[ray]`` if none) and the Morton code of the brick
    (``2**brick`` vertices a side) that holds it (``2**(3·_KEY_BITS)`` if none): the key that orders rays."""
    sx, sy, sz = float(start[ray, 0]), float(start[ray, 1]), float(start[ray, 2])
    dx, dy, dz = float(step[ray, 0]), float(step[ray, 1]), float(step[ray, 2])
    inverse_reach = 1.0 / max(abs(dx), abs(dy), abs(dz), 1e-12)
    count = counts[ray]
    k = 0
    while k < count:
        distance_gap, nx, ny, nz = _nearest_gap(sx + k * dx, sy + k * dy, sz + k * dz, gap, row, plane, cells)
        if distance_gap < 0:
            bx, by, bz = nx >> brick, ny >> brick, nz >> brick
            key = 0
            for bit in range(_KEY_BITS):
                key |= (((bx >> bit) & 1) << (3 * bit)) | (((by >> bit) & 1) << (3 * bit + 1)) | (((bz >> bit) & 1) << (3 * bit + 2))
            return k, key
        k += max(int(math.ceil((distance_gap - JUMP_MARGIN) * inverse_reach)), 1)
    return count, 1 << (3 * _KEY_BITS)


@numba.njit(cache=True, nogil=True)
def _march_ray(
    ray: int,
    k: int,
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
    """March ray ``ray`` from its sample ``k`` on: composite into ``out[ray]`` (zeroed here) and store its log
    transmittance; ``values`` is scratch (C,)."""
    channels = grid.shape[1]
    rx, ry = cells[0] + 1, cells[1] + 1
    sx, sy, sz = float(start[ray, 0]), float(start[ray, 1]), float(start[ray, 2])
    dx, dy, dz = float(step[ray, 0]), float(step[ray, 1]), float(step[ray, 2])
    inverse_reach = 1.0 / max(abs(dx), abs(dy), abs(dz), 1e-12)
    for c in range(out.shape[1]):
        out[ray, c] = 0.0
    log_t, transmittance = 0.0, 1.0
    count = counts[ray]
    while k < count:
        px, py, pz = sx + k * dx, sy + k * dy, sz + k * dz
        distance_gap = _nearest_gap(px, py, pz, gap, row, plane, cells)[0]
        if distance_gap >= 0:
            k += max(int(math.ceil((distance_gap - JUMP_MARGIN) * inverse_reach)), 1)
            continue
        # trilinear weights of the 8 vertices around the clamped position (as GridField.interpolate_vertices)
        qx = min(max(px, 0.0), float(cells[0]))
        qy = min(max(py, 0.0), float(cells[1]))
        qz = min(max(pz, 0.0), float(cells[2]))
        cx = min(int(math.floor(qx)), cells[0] - 1)
        cy = min(int(math.floor(qy)), cells[1] - 1)
        cz = min(int(math.floor(qz)), cells[2] - 1)
        fx, fy, fz = qx - cx, qy - cy, qz - cz
        gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
        i0 = cx + cy * rx + cz * rx * ry
        i2, i4 = i0 + rx, i0 + rx * ry
        i6 = i4 + rx
        w0, w1, w2, w3 = gx * gy * gz, fx * gy * gz, gx * fy * gz, fx * fy * gz
        w4, w5, w6, w7 = gx * gy * fz, fx * gy * fz, gx * fy * fz, fx * fy * fz
        for c in range(channels):
            values[c] = (w0 * grid[i0, c] + w1 * grid[i0 + 1, c] + w2 * grid[i2, c] + w3 * grid[i2 + 1, c]) + (
                w4 * grid[i4, c] + w5 * grid[i4 + 1, c] + w6 * grid[i6, c] + w7 * grid[i6 + 1, c]
            )
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
def _counting_order(keys: np.ndarray) -> np.ndarray:
    """Indices (R,) that sort the keys (R,) in [0, 2**(3·_KEY_BITS)] ascending (stable)."""
    bucket_start = np.zeros((1 << (3 * _KEY_BITS)) + 2, dtype=np.int64)
    for key in keys:
        bucket_start[key + 1] += 1
    for b in range(1, len(bucket_start)):
        bucket_start[b] += bucket_start[b - 1]
    order = np.empty(len(keys), dtype=np.int64)
    for ray in range(len(keys)):
        order[bucket_start[keys[ray]]] = ray
        bucket_start[keys[ray]] += 1
    return order


@numba.njit(cache=True, nogil=True)
def _first_hits_serial(start, step, counts, gap, row, plane, cells, brick, first, keys) -> None:  # noqa: ANN001
    for ray in range(start.shape[0]):
        first[ray], keys[ray] = _first_occupied(ray, start, step, counts, gap, row, plane, cells, brick)


@numba.njit(cache=True, nogil=True, parallel=True)
def _first_hits_parallel(start, step, counts, gap, row, plane, cells, brick, first, keys, chunks) -> None:  # noqa: ANN001
    rays = start.shape[0]
    for chunk in numba.prange(chunks):
        for ray in range(chunk * rays // chunks, (chunk + 1) * rays // chunks):
            first[ray], keys[ray] = _first_occupied(ray, start, step, counts, gap, row, plane, cells, brick)


@numba.njit(cache=True, nogil=True)
def _march_serial(order, first, start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, out, log_transmittance) -> None:  # noqa: ANN001
    values = np.empty(grid.shape[1], dtype=np.float64)
    for ray in order:
        _march_ray(ray, first[ray], start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, values, out, log_transmittance)


@numba.njit(cache=True, nogil=True, parallel=True)
def _march_parallel(order, first, start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, out, log_transmittance, chunks) -> None:  # noqa: ANN001
    rays = order.shape[0]
    for chunk in numba.prange(chunks):
        values = np.empty(grid.shape[1], dtype=np.float64)
        for i in range(chunk * rays // chunks, (chunk + 1) * rays // chunks):
            ray = order[i]
            _march_ray(ray, first[ray], start, step, counts, gap, row, plane, grid, cells, shift, scale, stop, with_position, values, out, log_transmittance)


def _brick_bits(resolution: tuple[int, int, int]) -> int:
    """log2 of the brick edge (vertices, at least 4) whose Morton codes order the rays: at most 2**_KEY_BITS bricks per padded axis."""
    largest, bits = max(resolution) + 1, 2
    while largest >> bits >= 1 << _KEY_BITS:
        bits += 1
    return bits


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
        grid: (V, C) raw channels (σ, 3 diffuse, C - 4 features), vertex-major (x fastest); float32 or float64.
        resolution: (Rx, Ry, Rz) vertices per axis.
        shift: added to raw σ before softplus; scale: multiplies the softplus (σ·δ of one render step).
        termination_transmittance: a ray stops once its transmittance falls below this.
        with_position: also composite the sample positions (vertex coordinates) as three more channels.
    Returns:
        composited (R, C - 1 [+ 3]) (Σ w_k c_k) and log transmittance (R,) after the last sample composited, float64 for
        float64 rays and float32 otherwise (the loop computes in float64).
    """
    if start.device.type != "cpu":
        raise ValueError(f"fused_march runs on the CPU; got tensors on {start.device}")
    rays, channels = start.shape[0], grid.shape[1]
    dtype = np.float64 if start.dtype == torch.float64 else np.float32
    out = np.empty((rays, channels - 1 + (3 if with_position else 0)), dtype=dtype)
    log_transmittance = np.empty(rays, dtype=dtype)
    first, keys = np.empty(rays, dtype=np.int64), np.empty(rays, dtype=np.int64)
    lattice = (
        np.ascontiguousarray(start.detach().numpy(), dtype=dtype),
        np.ascontiguousarray(step.detach().numpy(), dtype=dtype),
        np.ascontiguousarray(counts.numpy(), dtype=np.int64),
        table.gap.numpy(),
        table.row,
        table.plane,
    )
    cells = np.array([r - 1 for r in resolution], dtype=np.int64)
    shading = (grid.detach().numpy(), cells, float(shift), float(scale), float(termination_transmittance), bool(with_position), out, log_transmittance)
    threads = min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)
    if threads > 1 and rays > 1:
        chunks = min(rays, threads * _CHUNKS_PER_THREAD)
        with _PARALLEL_LAUNCH:
            numba.set_num_threads(threads)
            with record_function("march: first occupied sample, ray order"):
                _first_hits_parallel(*lattice, cells, _brick_bits(resolution), first, keys, chunks)
                order = _counting_order(keys)
            with record_function("march: skip, gather, shade, composite"):
                _march_parallel(order, first, *lattice, *shading, chunks)
    else:
        with record_function("march: first occupied sample, ray order"):
            _first_hits_serial(*lattice, cells, _brick_bits(resolution), first, keys)
            order = _counting_order(keys)
        with record_function("march: skip, gather, shade, composite"):
            _march_serial(order, first, *lattice, *shading)
    return torch.from_numpy(out), torch.from_numpy(log_transmittance)


def compile_ahead() -> None:
    """Compile (or load from numba's cache) the serial float32 loop now, once per process: a worker that loads a map then
    pays the first-use cost (about 4 s of CPU without a cache, a fraction of a second with one) before it serves, not in
    its first update. Renders one ray through a 2³ grid."""
    global _COMPILED
    if _COMPILED:
        return
    occupancy = torch.ones(2, 2, 2, dtype=torch.bool)
    start, step = torch.full((1, 3), 0.25), torch.full((1, 3), 0.25)
    fused_march(start, step, torch.tensor([3]), SkipTable(chebyshev_distance(occupancy, 1)), torch.zeros(8, 4), (2, 2, 2), 0.0, 1.0, 1e-3, True)
    _COMPILED = True
