"""Single-image pose estimation trials with the paper's initial distributions.

A trial renders (or is given) the image seen from a true pose, spreads particles by a protocol
around it, and runs noise-only prediction + update steps on that one image:

- ``inerf`` (iNeRF protocol, paper eq. 6): the start is the truth rotated by ±40° about a random
  axis and shifted by ±0.1 per axis; as in the original Loc-NeRF, particles are spread ±0.1 per
  axis around the start's position, each with its own ±40° rotation about a random axis.
- ``global``: particles uniform in a 2×2×2 cube around a ±1 per-axis offset of the truth, yaw
  uniform in ±180° about the world's up axis, roll and pitch known (from gravity).

Success is the paper's: translation error < 0.05 map units and rotation error < 5°.
"""

from __future__ import annotations

import logging
import math
import statistics
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from locnerf.field.protocol import RadianceMap, SurfaceRays, surface_distance_of, surface_renderer
from locnerf.filter.depth_measurement import DepthObservation, SurfaceDistanceLookup
from locnerf.filter.final_search import final_search
from locnerf.filter.initialization import uniform
from locnerf.filter.localizer import Localizer
from locnerf.geometry import make_pose, rotation_error_deg, translation_error
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import RenderRays

logger = logging.getLogger(__name__)

Protocol = Literal["inerf", "global"]
SUCCESS_TRANSLATION = 0.05
SUCCESS_ROTATION_DEG = 5.0


class TrialConfig(BaseModel):
    """How a single-image trial runs."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    protocol: Protocol = Field("inerf", description="Initial distribution: inerf (local) or global.")
    updates: int = Field(80, ge=1, description="Prediction + update steps on the image.")
    translation_offset: float = Field(0.1, ge=0, description="inerf: start offset and particle spread per axis (map units).")
    max_angle_deg: float = Field(40.0, ge=0, le=180, description="inerf: rotation perturbation bound (degrees).")
    global_half_width: float = Field(1.0, gt=0, description="global: half side of the particle cube and bound of its centre's offset.")
    up: tuple[float, float, float] = Field((0.0, 1.0, 0.0), description="global: the world's up axis (yaw axis).")


@dataclass
class TrialResult:
    """Outcome of one trial; histories have one entry for the start (0 forward passes, 0 s) and
    one per update, as the original's logs do."""

    translation_error: float
    rotation_error_deg: float
    seconds: float
    forward_passes: int
    rays: int = 0
    """Rays rendered in all (particles × pixels, summed over updates); ``forward_passes`` is that
    times the map's nominal samples per ray (an upper bound for grid maps, which skip empty space)."""
    history_translation: list[float] = field(default_factory=list)
    history_rotation_deg: list[float] = field(default_factory=list)
    history_forward_passes: list[int] = field(default_factory=list)
    history_rays: list[int] = field(default_factory=list)
    history_seconds: list[float] = field(default_factory=list)
    """Wall time since the trial's first update began, at each estimate."""
    final_pose: torch.Tensor | None = None
    """(4, 4) float64 estimate after the last update."""

    @property
    def success(self) -> bool:
        return self.translation_error < SUCCESS_TRANSLATION and self.rotation_error_deg < SUCCESS_ROTATION_DEG


def initialize_for_protocol(
    localizer: Localizer, truth: torch.Tensor, config: TrialConfig, generator: torch.Generator, offset: torch.Tensor | None = None
) -> None:
    """Spread the localizer's particles around ``truth`` (4, 4) by the configured protocol.

    Args:
        offset: (3,) translation offset of the start (e.g. from the original's logs); drawn from
            the protocol's range when None.
    """
    truth = truth.double().cpu()
    half_width = config.translation_offset if config.protocol == "inerf" else config.global_half_width
    if offset is None:
        offset = uniform(3, -half_width, half_width, generator)
    center = make_pose(truth[:3, :3], truth[:3, 3] + offset.double().cpu())
    if config.protocol == "inerf":
        localizer.initialize_inerf(center, config.translation_offset, config.max_angle_deg)
    else:
        localizer.initialize_global(center, config.global_half_width, config.up)


def run_trial(
    image: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    truth: torch.Tensor,
    render_rays: RenderRays,
    samples_per_ray: int,
    localizer: Localizer,
    config: TrialConfig,
    offset: torch.Tensor | None = None,
    render_surface: SurfaceRays | None = None,
    depth: DepthObservation | None = None,
    surface_distance: SurfaceDistanceLookup | None = None,
) -> TrialResult:
    """Localize one image whose true pose is ``truth`` (4, 4); the localizer is re-initialised.

    ``offset`` (3,) fixes the start's translation offset (logged starts); drawn when None.
    ``render_surface`` lets a localizer with ``measurement.warp`` weigh a converged cloud by re-projection.
    ``depth`` is the frame's depth image, used when the localizer's ``measurement.depth`` is set;
    ``surface_distance`` is the map's surface-distance layer (``measurement.depth.likelihood = "surface_distance"``).
    With the localizer's ``final_search`` set, the estimate after the last update is searched once more on fixed
    pixels (:mod:`locnerf.filter.final_search`); the histories get one more entry for it.
    """
    initialize_for_protocol(localizer, truth, config, localizer.generator, offset)
    truth = truth.double().cpu()
    result = TrialResult(math.inf, math.inf, 0.0, 0)

    def record(estimate: torch.Tensor, rays: int, seconds: float) -> None:
        result.history_translation.append(float(translation_error(estimate, truth)))
        result.history_rotation_deg.append(float(rotation_error_deg(estimate, truth)))
        result.history_rays.append(rays)
        result.history_forward_passes.append(rays * samples_per_ray)
        result.history_seconds.append(seconds)

    estimate = localizer.estimate().pose
    record(estimate, 0, 0.0)
    started = time.perf_counter()
    rays = 0
    for _ in range(config.updates):
        localizer.predict()
        rays += localizer.update(image, intrinsics, render_rays, render_surface, depth, surface_distance).rays
        estimate = localizer.estimate().pose
        record(estimate, rays, time.perf_counter() - started)
    search = localizer.config.final_search
    if search is not None:
        last = localizer.estimate()
        found = final_search(
            last.pose, last.covariance, image, intrinsics, render_rays, localizer.config.measurement, search, localizer.generator, localizer.device
        )
        rays += found.rays
        estimate = found.pose
        record(estimate, rays, time.perf_counter() - started)
    result.seconds = time.perf_counter() - started
    result.translation_error = result.history_translation[-1]
    result.rotation_error_deg = result.history_rotation_deg[-1]
    result.rays = rays
    result.forward_passes = rays * samples_per_ray
    result.final_pose = estimate
    return result


def run_trials(
    views: Iterable[tuple[torch.Tensor, torch.Tensor]],
    radiance_map: RadianceMap,
    localizer: Localizer,
    config: TrialConfig,
    show_progress: bool = True,
    total: int | None = None,
) -> list[TrialResult]:
    """Run one trial per (true pose (4, 4), image (H, W, 3)) view on a map; returns the results."""
    results = []
    for index, (truth, image) in enumerate(tqdm(views, total=total, desc=f"{config.protocol} trials", disable=not show_progress)):
        result = run_trial(
            image.to(radiance_map.device),
            radiance_map.default_intrinsics,
            truth,
            radiance_map.render_rays,
            radiance_map.samples_per_ray,
            localizer,
            config,
            render_surface=surface_renderer(radiance_map),
            surface_distance=surface_distance_of(radiance_map),
        )
        logger.info("trial %d: %.4f units, %.2f deg, %.1f s", index, result.translation_error, result.rotation_error_deg, result.seconds)
        results.append(result)
    return results


def summarize(results: list[TrialResult]) -> dict[str, float | int]:
    """The figures ``locnerf localize --json`` prints."""
    return {
        "trials": len(results),
        "success_rate": sum(r.success for r in results) / len(results),
        "median_translation_error": statistics.median(r.translation_error for r in results),
        "median_rotation_error_deg": statistics.median(r.rotation_error_deg for r in results),
        "mean_seconds_per_trial": statistics.fmean(r.seconds for r in results),
        "forward_passes": round(statistics.fmean(r.forward_passes for r in results)),
    }
