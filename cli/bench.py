"""``locnerf bench render|world|filter``: micro-benchmarks that print their figures (JSON with ``--json``).

* ``render`` (here) times a map's ``render_rays`` on the ray batches of the filter's update step
  (particles × pixels) against the nerf-pytorch-shaped MLP on the same rays;
* ``world`` (``cli.bench_world``) times the procedural world's ray renderer;
* ``filter`` (``cli.bench_filter``) times the filter's hot paths: likelihood, prediction,
  resampling, rotation averaging, estimate, message encode/decode.

``world`` and ``filter`` print a table (``cli.bench_table``) or JSON lines.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable

import torch

from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.field.map_file import load_map
from locnerf.field.nerf_pytorch import NerfMLP, NerfPytorchMap
from locnerf.render.rays import rays_from_poses_and_pixels
from locnerf_cli import bench_filter, bench_world


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf bench`` and its targets."""
    targets = parser.add_subparsers(dest="bench_target", required=True)
    render = targets.add_parser("render", help="update-step rendering speed of a map vs the nerf-pytorch MLP")
    render.add_argument("--map", required=True, help="map file")
    render.add_argument("--particles", type=int, default=300)
    render.add_argument("--pixels", type=int, default=64)
    render.add_argument("--repeats", type=int, default=10, help="timed update-step renders")
    render.add_argument("--mlp-rays", type=int, default=512, help="rays the MLP renders (its rate is scaled to the full batch)")
    render.add_argument("--device", default="auto")
    render.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the services use 1)")
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--json", action="store_true", help="print JSON")
    render.set_defaults(func=run_render)
    bench_world.add_target(targets)
    bench_filter.add_target(targets)


def _update_rays(radiance_map, particles: int, pixels: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays of one update step: reference poses jittered by ~2 cm / ~1°, random pixels: (P·M, 3) x2."""
    poses = radiance_map.reference_poses().float()
    choice = torch.randint(0, len(poses), (particles,), generator=generator)
    T_world_cam = poses[choice].clone()
    T_world_cam[:, :3, 3] += 0.02 * torch.randn(particles, 3, generator=generator)
    intrinsics = radiance_map.default_intrinsics
    uv = torch.rand(pixels, 2, generator=generator) * torch.tensor([intrinsics.width - 1.0, intrinsics.height - 1.0])
    origins, directions = rays_from_poses_and_pixels(T_world_cam, uv.round(), intrinsics)
    return origins.reshape(-1, 3), directions.reshape(-1, 3)


def _seconds_per_call(function: Callable[[], torch.Tensor], repeats: int, device: torch.device) -> float:
    function()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return (time.perf_counter() - start) / repeats


def run_render(args: argparse.Namespace) -> int:
    if args.threads < 1:
        raise LocnerfInputError(f"--threads {args.threads}: expected at least 1")
    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    torch.manual_seed(args.seed)
    generator = torch.Generator().manual_seed(args.seed)
    radiance_map = load_map(args.map, device)
    origins, directions = _update_rays(radiance_map, args.particles, args.pixels, generator)
    origins, directions = origins.to(device), directions.to(device)
    rays = len(origins)
    update_seconds = _seconds_per_call(lambda: radiance_map.render_rays(origins, directions), args.repeats, device)
    mlp = NerfPytorchMap(NerfMLP().to(device).eval(), NerfMLP().to(device).eval(), radiance_map.info, white_background=False)
    subset = min(args.mlp_rays, rays)
    mlp_seconds = _seconds_per_call(lambda: mlp.render_rays(origins[:subset], directions[:subset]), 1, device)
    mlp_rays_per_second = subset / mlp_seconds
    result = {
        "map": args.map,
        "device": str(device),
        "threads": torch.get_num_threads(),
        "particles": args.particles,
        "pixels": args.pixels,
        "rays": rays,
        "update_seconds": update_seconds,
        "update_hz": 1.0 / update_seconds,
        "rays_per_second": rays / update_seconds,
        "mlp_rays_measured": subset,
        "mlp_rays_per_second": mlp_rays_per_second,
        "mlp_update_hz": mlp_rays_per_second / rays,
        "mlp_samples_per_second": mlp_rays_per_second * mlp.samples_per_ray,
        "speedup_vs_mlp": (rays / update_seconds) / mlp_rays_per_second,
        "note": f"MLP timed on {subset} of the {rays} rays (scaled)" if subset < rays else "MLP timed on all rays",
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>24}: {value:.4g}" if isinstance(value, float) and math.isfinite(value) else f"{key:>24}: {value}")
    return 0
