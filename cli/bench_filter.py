"""``locnerf bench filter``: micro-benchmarks of the filter's hot paths, one stable line per target.

Targets (all at ``--particles`` N and ``--pixels`` M):

* ``likelihood``: the worker's measurement step on a map (``--map world`` by default): rays for
  N poses × M pixels, render, log-likelihoods;
* ``likelihood_converged``: the same for N poses within 1 cm and 0.6° of one view of the map (its
  first reference pose, or a sampled world camera), as a converged cloud renders;
* ``likelihood_warp``: those N poses weighed by re-projection (:mod:`locnerf.filter.warp`): the
  reference view rendered at every ``--warp-stride``-th pixel, M of its pixels warped into every pose;
* ``depth_rendered`` / ``depth_warp``: the depth term of an RGB-D frame (:mod:`locnerf.filter.depth_measurement`)
  for those N poses, its depth image the map's surface depth at the view: M depth pixels rendered from
  every pose, or the reference render with M depth points re-projected into every pose (the colour
  term not included; maps that can place surfaces only); ``depth_surface_distance``: the M depth
  pixels' points placed by every pose and looked up in the map's surface-distance layer (maps that have one);
* ``predict``: eq. 4 for N particles (odometry increment and tangent noise);
* ``resample_multinomial`` / ``resample_systematic``: N indices from N weights;
* ``rotation_mean``: weighted geodesic L2 mean of N rotations;
* ``estimate``: the full estimate (weighted mean pose and 6×6 covariance);
* ``encode_request`` / ``decode_request``: an UpdateRequest of N poses and M pixels;
* ``encode_result`` / ``decode_result``: an UpdateResult of N log-likelihoods;
* ``encode_image`` / ``decode_image``: a frame of the map's default camera size.

Each row is ``target  median_ms  p90_ms  calls_per_s`` over ``--repeats`` timed calls after one
untimed call (``--json``: one JSON object per line with the same fields and the settings), so two
runs can be compared line by line (``cli.bench_table``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch

from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import RadianceMap, surface_distance_of, surface_renderer
from locnerf.field.stored_map import StoredMap
from locnerf.filter.annealing import AnnealingStage
from locnerf.filter.depth_measurement import (
    DepthConfig,
    SurfaceDistanceLookup,
    render_depth_image,
    rendered_depth_log_likelihoods,
    sample_depth_pixels,
    surface_distance_log_likelihoods,
    warped_depth_log_likelihoods,
)
from locnerf.filter.estimate import estimate_from_particles
from locnerf.filter.measurement import observed_colours, particle_log_likelihoods, sample_pixels, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig, WarpConfig
from locnerf.filter.motion import propagate_poses
from locnerf.filter.particles import ParticleSet
from locnerf.filter.resampling import multinomial_resample, systematic_resample
from locnerf.filter.warp import render_reference, warp_log_likelihoods
from locnerf.geometry import se3_exp
from locnerf.geometry.averaging import geodesic_rotation_mean
from locnerf.maps.source import map_identity, open_map
from locnerf.messages.codec import decode, decode_image, encode, encode_image
from locnerf.messages.schemas import ImageHeader, UpdateRequest, UpdateResult
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import SurfaceRays, render_views
from locnerf_cli.bench_table import BenchTable


def add_target(targets: argparse._SubParsersAction) -> None:
    """Add ``filter`` to the targets of ``locnerf bench``."""
    parser = targets.add_parser("filter", help="the filter's hot paths: likelihood, prediction, resampling, rotation mean, codec, ...")
    parser.add_argument("--particles", type=int, default=300, help="N")
    parser.add_argument("--pixels", type=int, default=64, help="M")
    parser.add_argument("--repeats", type=int, default=20, help="timed calls per target")
    parser.add_argument("--map", default="world", help="map of the likelihood target: 'world' or a map file")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda (likelihood and prediction)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the services use 1)")
    parser.add_argument("--targets", help="comma-separated subset of the targets (default: all)")
    parser.add_argument("--warp-stride", type=int, default=2, help="likelihood_warp: the reference view's pixel stride")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.set_defaults(func=run)


def time_calls(function: Callable[[], object], repeats: int, device: torch.device) -> list[float]:
    """Seconds of ``repeats`` calls of ``function`` after one untimed call (synchronising CUDA)."""
    function()
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        seconds.append(time.perf_counter() - start)
    return seconds


def converged_targets(
    radiance_map: RadianceMap, particles: int, pixels: int, stride: int, device: torch.device, generator: torch.Generator
) -> dict[str, Callable[[], object]]:
    """``likelihood_converged``, ``likelihood_warp`` and the depth targets: N poses around one view of the map, its image
    (and, for the depth targets, its depth image) rendered once here."""
    intrinsics = radiance_map.default_intrinsics
    if isinstance(radiance_map, StoredMap):
        view = radiance_map.reference_poses()[0].double()
    else:
        view = radiance_map.sample_camera_pose(generator).double()
    view = view.to(device)
    sigma = torch.tensor([0.01] * 3 + [0.01] * 3, dtype=torch.float64, device=device)
    poses = (view[None] @ se3_exp(torch.randn(particles, 6, dtype=torch.float64, generator=generator).to(device) * sigma)).float()
    image = render_views(radiance_map.render_rays, view[None].float(), intrinsics)[0]
    measurement = MeasurementConfig(pixels=pixels, warp=WarpConfig(max_spread=1.0, pixels=pixels, stride=stride))
    pixel_uv = sample_pixels_of_image(image, measurement, generator).to(device)
    observed = observed_colours(image, pixel_uv)
    render_surface = surface_renderer(radiance_map)
    targets: dict[str, Callable[[], object]] = {
        "likelihood_converged": lambda: particle_log_likelihoods(poses, pixel_uv, observed, intrinsics, radiance_map.render_rays),
    }
    if render_surface is not None:
        targets["likelihood_warp"] = lambda: warp_log_likelihoods(
            poses, render_reference(render_surface, view.cpu(), intrinsics, measurement, generator), image, intrinsics
        )
        targets |= depth_targets(
            render_surface,
            view,
            poses,
            measurement.model_copy(update={"depth": DepthConfig(pixels=pixels)}),
            intrinsics,
            generator,
            surface_distance_of(radiance_map),
        )
    return targets


def depth_targets(
    render_surface: SurfaceRays,
    view: torch.Tensor,
    poses: torch.Tensor,
    measurement: MeasurementConfig,
    intrinsics: PinholeIntrinsics,
    generator: torch.Generator,
    surface_distance: SurfaceDistanceLookup | None = None,
) -> dict[str, Callable[[], object]]:
    """``depth_rendered``, ``depth_warp`` and, for maps with a surface-distance layer, ``depth_surface_distance``: the depth
    term of poses (N, 4, 4) for the map's own depth image at ``view`` (4, 4)."""
    config = measurement.depth
    observation = render_depth_image(render_surface, view.float(), intrinsics)
    depth_pixels = sample_depth_pixels(observation, config, generator).to(view.device)
    looked_up = {}
    if surface_distance is not None:
        looked_up["depth_surface_distance"] = lambda: surface_distance_log_likelihoods(poses, observation, depth_pixels, surface_distance, config)
    return looked_up | {
        "depth_rendered": lambda: rendered_depth_log_likelihoods(poses, observation, depth_pixels, render_surface, config),
        "depth_warp": lambda: warped_depth_log_likelihoods(
            poses, render_reference(render_surface, view.cpu(), intrinsics, measurement, generator, config.pixels, intrinsics).depth_points, observation, config
        ),
    }


def build_targets(
    particles: int, pixels: int, map_spec: str, device: torch.device, generator: torch.Generator, warp_stride: int = 2
) -> dict[str, Callable[[], object]]:
    """Every target as a no-argument callable over inputs built here once."""
    radiance_map = open_map(map_spec, device)
    intrinsics = radiance_map.default_intrinsics
    bounds = radiance_map.camera_bounds().double()
    tangents = torch.randn(particles, 6, dtype=torch.float64, generator=generator) * torch.tensor([0.3, 0.3, 0.3, 0.0, 0.0, 0.0], dtype=torch.float64)
    poses = se3_exp(tangents)
    poses[:, :3, 3] = bounds[0] + torch.rand(particles, 3, dtype=torch.float64, generator=generator) * (bounds[1] - bounds[0])
    pixel_uv = sample_pixels(intrinsics.height, intrinsics.width, pixels, generator).float()
    observed = torch.rand(pixels, 3, generator=generator)
    weights = torch.rand(particles, dtype=torch.float64, generator=generator)
    weights /= weights.sum()
    increment = se3_exp(torch.tensor([[0.01, 0.0, 0.0, 0.02, 0.0, 0.0]], dtype=torch.float64))[0]
    sigma = torch.tensor([0.02] * 3 + [0.01] * 3, dtype=torch.float64)
    particle_set = ParticleSet(poses=poses, log_weights=weights.log(), ids=torch.arange(particles), parent_ids=torch.arange(particles))
    request = UpdateRequest(
        request_id="bench",
        shard=0,
        map_checksum=map_identity(radiance_map),
        epoch=0,
        generation=0,
        ids=list(range(particles)),
        poses=poses.reshape(-1, 16).tolist(),
        pixels=pixel_uv.tolist(),
        observed_rgb=observed.tolist(),
        intrinsics=intrinsics,
    )
    result = UpdateResult(
        request_id="bench",
        shard=0,
        worker_id="bench",
        epoch=0,
        generation=0,
        ids=list(range(particles)),
        log_likelihoods=torch.randn(particles, dtype=torch.float64, generator=generator).tolist(),
        compute_seconds=0.0,
    )
    frame = np.random.default_rng(0).integers(0, 256, (intrinsics.height, intrinsics.width, 3), dtype=np.uint8)
    header = ImageHeader(stamp=0.0, encoding="rgb8", width=intrinsics.width, height=intrinsics.height, intrinsics=intrinsics)
    request_bytes, result_bytes, image_bytes = encode(request), encode(result), encode_image(header, frame)
    poses_on_device, float_poses = poses.to(device), poses.float().to(device)
    pixels_on_device, observed_on_device = pixel_uv.to(device), observed.to(device)
    return {
        "likelihood": lambda: particle_log_likelihoods(float_poses, pixels_on_device, observed_on_device, intrinsics, radiance_map.render_rays),
        **converged_targets(radiance_map, particles, pixels, warp_stride, device, generator),
        "predict": lambda: propagate_poses(poses_on_device, increment, sigma, generator),
        "resample_multinomial": lambda: multinomial_resample(weights, particles, generator),
        "resample_systematic": lambda: systematic_resample(weights, particles, generator),
        "rotation_mean": lambda: geodesic_rotation_mean(poses[:, :3, :3], weights),
        "estimate": lambda: estimate_from_particles(particle_set, AnnealingStage.COARSE),
        "encode_request": lambda: encode(request),
        "decode_request": lambda: decode(request_bytes, UpdateRequest),
        "encode_result": lambda: encode(result),
        "decode_result": lambda: decode(result_bytes, UpdateResult),
        "encode_image": lambda: encode_image(header, frame),
        "decode_image": lambda: decode_image(image_bytes),
    }


def run(args: argparse.Namespace) -> int:
    for name, value in (
        ("--particles", args.particles),
        ("--pixels", args.pixels),
        ("--repeats", args.repeats),
        ("--threads", args.threads),
        ("--warp-stride", args.warp_stride),
    ):
        if value < 1:
            raise LocnerfInputError(f"{name} {value}: expected at least 1")
    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    generator = torch.Generator().manual_seed(args.seed)
    targets = build_targets(args.particles, args.pixels, args.map, device, generator, args.warp_stride)
    chosen = args.targets.split(",") if args.targets else list(targets)
    unknown = sorted(set(chosen) - set(targets))
    if unknown:
        raise LocnerfInputError(f"--targets {unknown}: expected names among {sorted(targets)}")
    settings = {"particles": args.particles, "pixels": args.pixels, "map": args.map, "device": str(device), "threads": args.threads}
    table = BenchTable(("target", "median_ms", "p90_ms", "calls_per_s"), settings, args.json)
    for name in chosen:
        seconds = time_calls(targets[name], args.repeats, device)
        median, p90 = float(np.median(seconds)), float(np.percentile(seconds, 90))
        table.row({"target": name, "median_ms": round(1000 * median, 4), "p90_ms": round(1000 * p90, 4), "calls_per_s": round(1.0 / median, 1)})
    return 0
