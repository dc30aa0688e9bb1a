"""Speed of the procedural world's renderer (the ``locnerf bench world`` command prints it).

Median milliseconds per ``render_rays`` call over rays through random pixels of plausible cameras.
"""

from __future__ import annotations

import statistics
import time

import torch

from locnerf.render.rays import rays_from_poses_and_pixels
from locnerf.sim.world import ProceduralWorld


def rays_from_random_cameras(world: ProceduralWorld, count: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``count`` rays (count, 3) + (count, 3), float64: 64 random pixels from each of count / 64 sampled poses."""
    intrinsics = world.default_intrinsics
    cameras = max(1, count // 64)
    poses = torch.stack([world.sample_camera_pose(generator) for _ in range(cameras)])
    pixels = torch.rand(64, 2, dtype=torch.float64, generator=generator) * torch.tensor([intrinsics.width, intrinsics.height], dtype=torch.float64)
    origins, directions = rays_from_poses_and_pixels(poses, pixels, intrinsics)
    return origins.reshape(-1, 3)[:count], directions.reshape(-1, 3)[:count]


def median_milliseconds(world: ProceduralWorld, origins: torch.Tensor, directions: torch.Tensor, repeats: int) -> float:
    """Median wall time of ``world.render_rays`` in milliseconds over ``repeats`` calls (after one warm-up)."""
    world.render_rays(origins, directions)
    timings = []
    for _ in range(repeats):
        if origins.is_cuda:
            torch.cuda.synchronize()
        start = time.perf_counter()
        world.render_rays(origins, directions)
        if origins.is_cuda:
            torch.cuda.synchronize()
        timings.append((time.perf_counter() - start) * 1e3)
    return statistics.median(timings)


def benchmark_world(rays: int, repeats: int, device: torch.device, seed: int = 0) -> list[dict[str, object]]:
    """Median ``render_rays`` milliseconds of the default world for float32 and float64, one dict each."""
    if rays < 1 or repeats < 1:
        raise ValueError(f"rays and repeats: expected >= 1, got {rays} and {repeats}")
    world = ProceduralWorld.default(device)
    origins, directions = rays_from_random_cameras(world, rays, torch.Generator().manual_seed(seed))
    results = []
    for dtype in (torch.float32, torch.float64):
        ms = median_milliseconds(world, origins.to(device, dtype), directions.to(device, dtype), repeats)
        dtype_name = str(dtype).removeprefix("torch.")
        results.append({"rays": rays, "dtype": dtype_name, "device": str(device), "threads": torch.get_num_threads(), "median_ms": round(ms, 3)})
    return results
