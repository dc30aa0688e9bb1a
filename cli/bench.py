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
from torch.profiler import record_function

from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.field.map_file import load_map
from locnerf.field.nerf_pytorch import NerfMLP, NerfPytorchMap
from locnerf.field.protocol import surface_renderer
from locnerf.filter.measurement import particle_log_likelihoods
from locnerf.render.rays import rays_from_poses_and_pixels
from locnerf_cli import bench_filter, bench_render, bench_world


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
    render.add_argument("--cloud", choices=bench_render.CLOUDS, default="views", help="particle poses (cli.bench_render): views, converged or spread")
    render.add_argument("--depth", action="store_true", help="also time the surface render (the depth term's rays) on the same rays")
    render.add_argument(
        "--marcher", choices=("fused", "torch"), default="fused", help="grid maps on the CPU: compiled per-ray loop, or the batched torch marcher (GPUs)"
    )
    render.add_argument("--profile", action="store_true", help="also print the update step's CPU time by stage (torch.profiler)")
    render.add_argument(
        "--compare-marchers", action="store_true", help="metric grid maps: also print the largest differences between the compiled and the torch marcher"
    )
    render.add_argument("--json", action="store_true", help="print JSON")
    render.set_defaults(func=run_render)
    bench_world.add_target(targets)
    bench_filter.add_target(targets)


def _update_poses_and_pixels(radiance_map, cloud: str, particles: int, pixels: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Poses (N, 4, 4) of the cloud (:func:`bench_render.cloud_poses`) and M random integer pixels (M, 2) of one update step."""
    T_world_cam = bench_render.cloud_poses(radiance_map, cloud, particles, generator)
    intrinsics = radiance_map.default_intrinsics
    uv = torch.rand(pixels, 2, generator=generator) * torch.tensor([intrinsics.width - 1.0, intrinsics.height - 1.0])
    return T_world_cam, uv.round()


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
    if hasattr(radiance_map, "field"):
        radiance_map.field.fused_march = args.marcher == "fused"
    poses, pixels = _update_poses_and_pixels(radiance_map, args.cloud, args.particles, args.pixels, generator)
    poses, pixels = poses.to(device), pixels.to(device)
    intrinsics = radiance_map.default_intrinsics
    origins, directions = (rays.reshape(-1, 3) for rays in rays_from_poses_and_pixels(poses, pixels, intrinsics))
    rays = len(origins)
    update_seconds = _seconds_per_call(lambda: radiance_map.render_rays(origins, directions), args.repeats, device)
    render_surface = surface_renderer(radiance_map) if args.depth else None
    if args.depth and render_surface is None:
        raise LocnerfInputError(f"--depth: the map {args.map} cannot place surfaces (NDC or MLP map); expected a metric grid map or the world")
    surface_seconds = _seconds_per_call(lambda: render_surface(origins, directions), args.repeats, device) if render_surface else None
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
        "cloud": args.cloud,
        "marcher": args.marcher if device.type == "cpu" else "torch",  # the compiled loop runs on the CPU only
        "rays": rays,
        "update_seconds": update_seconds,
        "update_hz": 1.0 / update_seconds,
        "rays_per_second": rays / update_seconds,
        **({"surface_seconds": surface_seconds, "colour_and_depth_seconds": update_seconds + surface_seconds} if surface_seconds else {}),
        "mlp_rays_measured": subset,
        "mlp_rays_per_second": mlp_rays_per_second,
        "mlp_update_hz": mlp_rays_per_second / rays,
        "mlp_samples_per_second": mlp_rays_per_second * mlp.samples_per_ray,
        "speedup_vs_mlp": (rays / update_seconds) / mlp_rays_per_second,
        "note": f"MLP timed on {subset} of the {rays} rays (scaled)" if subset < rays else "MLP timed on all rays",
    }
    if args.compare_marchers:
        if not hasattr(radiance_map, "field") or surface_renderer(radiance_map) is None:
            raise LocnerfInputError(f"--compare-marchers: the map {args.map} is not a metric grid map")
        result["fused_vs_torch"] = bench_render.marcher_differences(radiance_map, origins.cpu(), directions.cpu())
    if args.profile:
        observed = torch.rand(args.pixels, 3, generator=generator).to(device)

        def update() -> None:
            particle_log_likelihoods(poses, pixels, observed, intrinsics, radiance_map.render_rays)
            if render_surface is not None:
                with record_function("update: surface render (depth rays)"):
                    render_surface(origins, directions)

        result["profile_ms"] = bench_render.stage_profile(update, args.repeats)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            if key != "profile_ms":
                print(f"{key:>24}: {value:.4g}" if isinstance(value, float) and math.isfinite(value) else f"{key:>24}: {value}")
        for stage, milliseconds in result.get("profile_ms", {}).items():
            print(f"{milliseconds:10.2f} ms  {stage}")
    return 0
