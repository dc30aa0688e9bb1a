"""Where a frame's own depth puts its camera in the map: how far the depth term's peak lies from the ground truth.

An RGB-D likelihood multiplies a colour term and a depth term (:mod:`locnerf.filter.depth_measurement`).
With the map's surface-distance layer (:mod:`locnerf.field.surface_distance`), the depth term of a pose
depends on ``Σ_j min(d_j², c²)``, ``d_j`` the distance from depth reading j, placed by the pose's depth
camera, to the nearest surface the training frames measured. For each frame, this module starts at the
ground-truth pose and minimises that sum over the pose (L-BFGS on the trilinear lookup's gradient, with
the rotation and translation as one tangent vector ``ξ``, ``T = T_true · Exp(ξ)``): the pose the depth
term alone favours near the truth. Its distance from the truth is the **depth offset**: where the map's
measured geometry and the ground truth of a frame disagree (a drift of the ground truth between sequences,
the depth sensor's own distortion, the depth camera's calibration), a filter weighing depth is pulled
that far from the truth by that term, whatever its colour term says.

On frames the layer was built from (the training split), the offset measures the fit itself: their
readings placed by their own poses made the surface.

Beside it, the **colour offset** (optional, :class:`ColourPeak`): the colour term's own best pose near the
truth, found by the single-image final search (:func:`locnerf.filter.final_search.final_search`: the
cross-entropy method on pixels drawn once, rendered from the map) started at the truth, with the gain in
nats it found over the truth on those pixels (a small gain: the colour term hardly prefers its peak).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.field.surface_distance import SurfaceDistance
from locnerf.filter.depth_measurement import DepthObservation, reading_points
from locnerf.filter.final_search import FinalSearchConfig, final_search
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.geometry import rotation_error_deg, translation_error
from locnerf.geometry.se3 import se3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import RenderRays

TRANSLATION_WITHIN = 0.03
"""Metres: the kitchen's tracking and back-on-track bound, for the share of frames whose offset is within it (and 1°)."""
ROTATION_WITHIN_DEG = 1.0


@dataclass(frozen=True)
class ColourPeak:
    """How the colour offset is searched: the map's renderer, the likelihood (``measurement``: exponent, sampling
    rule, exposure model) and the search (on at most the image's pixels), from the truth with ``rotation_deg`` and
    ``position`` (map units) standard deviations per axis in its first round."""

    render_rays: RenderRays
    measurement: MeasurementConfig
    search: FinalSearchConfig = FinalSearchConfig(pixels=2048, iterations=12, inflation=1.0, min_position=0.002, min_rotation_deg=0.05)
    rotation_deg: float = 1.5
    position: float = 0.03

    def offset(self, truth: torch.Tensor, image: torch.Tensor, intrinsics: PinholeIntrinsics, generator: torch.Generator) -> tuple[torch.Tensor, float]:
        """The colour term's best pose (4, 4) float64 found near ``truth`` for ``image`` (H, W, 3), and its gain in nats over the truth."""
        spread = torch.tensor([math.radians(self.rotation_deg)] * 3 + [self.position] * 3, dtype=torch.float64)
        search = self.search.model_copy(update={"pixels": min(self.search.pixels, image.shape[0] * image.shape[1])})
        found = final_search(truth, torch.diag(spread**2), image, intrinsics, self.render_rays, self.measurement, search, generator)
        return found.pose, found.log_likelihood - found.start_log_likelihood


def depth_camera_points(
    depth: torch.Tensor, intrinsics: PinholeIntrinsics, count: int, generator: torch.Generator, min_depth: float, max_depth: float
) -> torch.Tensor:
    """Up to ``count`` valid readings of a depth image (Hd, Wd), drawn uniformly without replacement, as points
    (P, 3) float64 in the depth camera's frame (OpenGL axes), the pixel coordinates as the filter's depth term takes them."""
    rows, columns = torch.nonzero(torch.isfinite(depth) & (depth >= min_depth) & (depth <= max_depth), as_tuple=True)
    chosen = torch.randperm(len(rows), generator=generator)[:count]
    pixels = torch.stack((columns[chosen], rows[chosen]), dim=-1).double()
    return reading_points(DepthObservation(depth, intrinsics), pixels)


def fit_depth_to_surface(start: torch.Tensor, points: torch.Tensor, T_cam_depth: torch.Tensor, surface: SurfaceDistance, iterations: int = 30) -> torch.Tensor:
    """The pose (4, 4) float64 near ``start`` (4, 4) whose depth camera ``T · T_cam_depth`` places the depth-camera
    points (P, 3) closest to the layer's surfaces: the minimum of ``mean_j d_j²``, ``d_j`` the lookup (truncated
    by the layer), by L-BFGS (strong Wolfe line search) over ``ξ`` in ``start · Exp(ξ)``."""
    xi = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.LBFGS([xi], lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe")
    offset = T_cam_depth.double()

    def loss() -> torch.Tensor:
        optimiser.zero_grad()
        depth_pose = start.double() @ se3_exp(xi) @ offset
        world = points @ depth_pose[:3, :3].T + depth_pose[:3, 3]
        value = surface.lookup(world).double().pow(2).mean()
        value.backward()
        return value

    optimiser.step(loss)
    return start.double() @ se3_exp(xi.detach())


def depth_agreement(
    frames: PosedImages,
    surface: SurfaceDistance,
    points: int = 4000,
    seed: int = 0,
    min_depth: float = 0.1,
    max_depth: float = 6.0,
    colour: ColourPeak | None = None,
) -> dict[str, object]:
    """Each frame's depth offset (:func:`fit_depth_to_surface` from its own pose) in metres and degrees, and with
    ``colour`` its colour offset.

    Args:
        frames: frames with depth images, in the map's frame (``frames.normalization.scale`` map units per metre).
        surface: the map's surface-distance layer.
        points: readings per frame.
    Returns:
        ``{"frames": [{"name", "translation_m", "rotation_deg"}], "summary": {"frames", "translation_median_m",
        "translation_p90_m", "rotation_median_deg", "rotation_p90_deg", "within_3cm_1deg"}}``; with ``colour``, each
        frame also has ``colour_translation_m``, ``colour_rotation_deg`` and ``colour_gain_nats``, and the report a
        ``colour_summary`` of the colour offsets (the same keys).
    Raises:
        DatasetError: frames without depth images.
        LocnerfInputError: ``points`` < 6 (too few to fix a pose).
    """
    if frames.depths is None or frames.depth_intrinsics is None:
        raise DatasetError(f"{frames.source}: the depth offset needs depth images")
    if points < 6:
        raise LocnerfInputError(f"points={points}: expected at least 6 readings per frame to fix a pose")
    generator = torch.Generator().manual_seed(seed)
    colour_generator = torch.Generator().manual_seed(seed)  # its own: the depth readings drawn do not depend on ``colour``
    offset = frames.T_cam_depth if frames.T_cam_depth is not None else torch.eye(4, dtype=torch.float64)
    scale = frames.normalization.scale
    rows = []
    for position in range(len(frames)):
        truth = frames.T_world_cam[position].double()
        local = depth_camera_points(frames.depths[position], frames.depth_intrinsics, points, generator, min_depth * scale, max_depth * scale)
        if len(local) < 6:
            continue
        fitted = fit_depth_to_surface(truth, local, offset, surface)
        row = {"name": frames.names[position], **offset_of(fitted, truth, scale)}
        if colour is not None:
            peak, gain = colour.offset(truth, frames.images[position], frames.intrinsics, colour_generator)
            row |= {f"colour_{key}": value for key, value in offset_of(peak, truth, scale).items()} | {"colour_gain_nats": gain}
        rows.append(row)
    report: dict[str, object] = {"frames": rows, "summary": summary_of(rows)}
    if colour is not None:
        report["colour_summary"] = summary_of([{key.removeprefix("colour_"): value for key, value in row.items()} for row in rows])
    return report


def offset_of(pose: torch.Tensor, truth: torch.Tensor, scale: float) -> dict[str, float]:
    """``translation_m`` and ``rotation_deg`` of ``pose`` (4, 4) from ``truth`` (4, 4), map units ``scale`` per metre."""
    return {"translation_m": float(translation_error(pose, truth)) / scale, "rotation_deg": float(rotation_error_deg(pose, truth))}


def summary_of(rows: list[dict]) -> dict[str, float | int | None]:
    """Medians, 90th percentiles (nearest rank) and the share of frames within 3 cm and 1° of the truth."""
    if not rows:
        return {"frames": 0}
    translations = sorted(row["translation_m"] for row in rows)
    rotations = sorted(row["rotation_deg"] for row in rows)
    p90 = max(0, math.ceil(0.9 * len(rows)) - 1)
    within = sum(row["translation_m"] <= TRANSLATION_WITHIN and row["rotation_deg"] <= ROTATION_WITHIN_DEG for row in rows)
    return {
        "frames": len(rows),
        "translation_median_m": statistics.median(translations),
        "translation_p90_m": translations[p90],
        "rotation_median_deg": statistics.median(rotations),
        "rotation_p90_deg": rotations[p90],
        "within_3cm_1deg": within / len(rows),
    }
