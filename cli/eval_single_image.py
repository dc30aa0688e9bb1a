"""``locnerf eval single-image`` and ``locnerf eval global`` on a map and its real images."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import torch
from tqdm import tqdm

from locnerf.config import load_config, preset
from locnerf.data import read_dataset
from locnerf.data.colour_camera import read_on_map_camera
from locnerf.data.posed_images import frame_change
from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.eval.paper_logs import read_logged_trials
from locnerf.eval.plots import plot_error_curves, plot_images_beside_renders, plot_mean_error_against_rays, plot_success_against_rays
from locnerf.eval.real_data import (
    in_truth_units,
    logged_curve,
    logged_views,
    mean_error_by_budget,
    result_curve,
    run_views,
    seeded_views,
    success_by_budget,
    totals,
    trial_record,
    view_in_frame,
)
from locnerf.eval.single_image import TrialConfig
from locnerf.filter.localizer import Localizer
from locnerf.maps.keyframes import recovery_keyframes
from locnerf.maps.source import open_map
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from locnerf_cli.flags import NO_DEPTH_HELP, add_poses_argument, from_flags, without_depth

logger = logging.getLogger(__name__)

PROTOCOLS = {"single-image": ("inerf", "llff", 100), "global": ("global", "llff_global", 150)}


def register(subparsers: argparse._SubParsersAction) -> None:
    for name, (protocol, default_preset, updates) in PROTOCOLS.items():
        parser = subparsers.add_parser(name, help=f"{protocol} protocol on real images, beside the original's logs")
        parser.add_argument("--map", required=True, help="map file (or 'world')")
        parser.add_argument("--data", required=True, type=Path, help="the data set the views come from")
        parser.add_argument("--downscale", type=int, default=None, help="image divisor when reading --data (reader default if unset)")
        parser.add_argument("--starts", type=Path, default=None, help="folder of the original's logs: reuse their frames and starts")
        parser.add_argument("--scene", default=None, help="scene name in the logs (default: the data folder's name)")
        parser.add_argument("--trials", type=int, default=0, help="seeded trials in addition to the logged starts")
        parser.add_argument("--split", default="all", help="split the seeded views are drawn from (all, train, test)")
        parser.add_argument("--updates", type=int, default=updates, help="update steps per trial")
        parser.add_argument("--preset", default=default_preset, help="filter preset")
        parser.add_argument("--config", default=None, help="TOML localizer configuration (overrides --preset)")
        parser.add_argument("--no-depth", action="store_true", help=NO_DEPTH_HELP)
        parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
        parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
        parser.add_argument("--plots", type=Path, default=None, help="folder for PNG figures")
        parser.add_argument("--json", action="store_true", help="print the full report as JSON")
        add_poses_argument(parser)
        parser.set_defaults(func=run, protocol=protocol)


def run(args: argparse.Namespace) -> int:
    if args.trials < 0 or (args.trials == 0 and args.starts is None):
        raise LocnerfInputError(f"--trials {args.trials}: expected >= 1 seeded trials, or --starts with logged ones")
    device = resolve_device(args.device)
    radiance_map = open_map(args.map, device)
    own = read_on_map_camera(args.data, radiance_map, args.poses, in_map_frame=False, split=args.split, downscale=args.downscale)
    pool = own.in_frame(radiance_map.normalization)
    # Distances are the ground truth's: an aligned SfM map's units differ from its frame's by the fitted scale.
    units = radiance_map.normalization.scale / own.normalization.scale
    generator = torch.Generator().manual_seed(args.seed)
    views = []
    if args.starts is not None:
        every_frame = (
            own if args.split == "all" else read_on_map_camera(args.data, radiance_map, args.poses, in_map_frame=False, split="all", downscale=args.downscale)
        )
        trials = read_logged_trials(args.starts, scene=args.scene or args.data.name)
        logged = logged_views(every_frame, trials, held_out_frames(args.data, "all", args.downscale))
        move = frame_change(every_frame.normalization, radiance_map.normalization)
        views += logged if pool is own else [view_in_frame(view, move) for view in logged]
    if args.trials:
        views += seeded_views(pool, args.trials, generator, held_out_frames(args.data, args.split, args.downscale))
    config = without_depth(load_config(args.config) if args.config else preset(args.preset), args.no_depth)
    keyframes = recovery_keyframes(config, radiance_map, pool.intrinsics, args.seed + 2) if args.protocol == "global" else None
    localizer = Localizer(config, generator, device=device, keyframes=keyframes)
    spreads = {"translation_offset": TrialConfig().translation_offset * units, "global_half_width": TrialConfig().global_half_width * units}
    trial_config = from_flags(TrialConfig, {"protocol": args.protocol, "updates": args.updates, "up": radiance_map.normalization.up, **spreads})
    results = []
    for view in tqdm(views, desc=f"{args.protocol} trials", disable=args.json):
        results += [in_truth_units(result, units) for result in run_views([view], radiance_map, pool.intrinsics, localizer, trial_config)]
        logger.info("frame %d: %.4f units, %.2f deg, %.1f s", view.frame, results[-1].translation_error, results[-1].rotation_error_deg, results[-1].seconds)
    records = [trial_record(v, r) for v, r in zip(views, results)]
    report = {
        "protocol": args.protocol,
        "map": args.map,
        "data": str(args.data),
        "poses": args.poses,
        "seed": args.seed,
        "updates": args.updates,
        "particles": config.particles,
        "pixels": config.measurement.pixels,
        "depth": config.measurement.depth.model_dump() if config.measurement.depth is not None and pool.depths is not None else None,
        "device": str(device),
        "map_units_per_truth_unit": units,
        "totals": totals(records),
        "trials": records,
    }
    if args.plots is not None:
        report["plots"] = write_plots(args.plots, args.protocol, views, results)
        report["plots"].append(str(write_render_panels(args.plots / f"{args.protocol}_image_vs_render.png", radiance_map, pool.intrinsics, views, results)))
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for subset, figures in report["totals"].items():
            if figures:
                print(f"{subset:>34}: " + ", ".join(f"{k} {v:.4g}" for k, v in figures.items()))
    return 0


def held_out_frames(data: Path, split: str, downscale: int | None) -> set[int]:
    """Frames the map did not train on: none of ``train``; otherwise those of the data set's
    ``test`` split (every 8th image for LLFF, the test folder for NeRF-synthetic)."""
    if split == "train":
        return set()
    return set(read_dataset(data, split="test", downscale=downscale).indices)


def write_render_panels(path: Path, radiance_map, intrinsics: PinholeIntrinsics, views, results, count: int = 3, width: int = 160) -> Path:
    """The first ``count`` trials' camera images beside the map rendered at their final estimates."""
    small = intrinsics.scaled(min(1.0, width / intrinsics.width))
    panels = []
    for view, result in list(zip(views, results))[:count]:
        image = torch.nn.functional.interpolate(view.image.permute(2, 0, 1)[None].float(), size=(small.height, small.width), mode="area")[0].permute(1, 2, 0)
        rendering = render_image(radiance_map.render_rays, result.final_pose.to(radiance_map.device), small)
        verdict = "success" if result.success else "failure"
        panels.append((f"{view.name} ({result.translation_error:.3f}, {result.rotation_error_deg:.2f}°, {verdict})", image, rendering.cpu()))
    return plot_images_beside_renders(panels, path, "camera image beside the map's rendering at the estimated pose")


def write_plots(folder: Path, protocol: str, views, results) -> list[str]:
    """Our error curves (against rays rendered and wall time); success ratio and mean error against
    rays rendered, ours beside the original's logged Loc-NeRF and iNeRF runs (paper Fig. 2).

    Rays, not forward passes, are the common budget: the original took 128 samples per ray, our
    grid maps a varying number (empty space is skipped)."""
    written = [
        str(plot_error_curves(results, folder / f"{protocol}_error_curves.png", f"{protocol} protocol: our error against rays rendered")),
        str(plot_error_curves(results, folder / f"{protocol}_error_vs_time.png", f"{protocol} protocol: our error against wall time", against="seconds")),
    ]
    curves = {"locnerf (ours), all trials": [result_curve(r) for r in results]}
    logged = [(view, result) for view, result in zip(views, results) if view.logged is not None]
    if logged:
        curves["locnerf (ours), logged starts"] = [result_curve(r) for _, r in logged]
        for label, attribute in (("Loc-NeRF (original logs)", "locnerf"), ("iNeRF (original logs)", "inerf")):
            runs = [(getattr(view.logged, attribute), view.logged.truth) for view, _ in logged]
            if all(run is not None and run.rays is not None for run, _ in runs):
                curves[label] = [logged_curve(run, truth) for run, truth in runs]
    highest = max(curve[0][-1] for group in curves.values() for curve in group)
    budgets = sorted({int(highest * f) for f in torch.logspace(-3, 0, 40).tolist()})
    success = {name: (budgets, success_by_budget(group, budgets)) for name, group in curves.items()}
    written.append(str(plot_success_against_rays(success, folder / f"{protocol}_success_vs_rays.png", f"{protocol} protocol: success ratio")))
    means = {name: (budgets, *mean_error_by_budget(group, budgets)) for name, group in curves.items()}
    written.append(str(plot_mean_error_against_rays(means, folder / f"{protocol}_mean_error_vs_rays.png", f"{protocol} protocol: mean error")))
    return written
