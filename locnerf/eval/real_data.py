"""Single-image experiments on real posed images, side by side with the original's logged runs.

A *view* is one real image with its true pose. Views come from the original Loc-NeRF's logged
trials (same frame, same start offset: our result and theirs are on the same starts) or are drawn
from a seed (any frame, including held-out ones that the map never saw).
"""

from __future__ import annotations

import bisect
import statistics
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.eval.paper_logs import LoggedRun, LoggedTrial
from locnerf.eval.single_image import SUCCESS_ROTATION_DEG, SUCCESS_TRANSLATION, TrialConfig, TrialResult, run_trial
from locnerf.field.protocol import RadianceMap, surface_distance_of, surface_renderer
from locnerf.filter.depth_measurement import DepthObservation
from locnerf.filter.localizer import Localizer
from locnerf.geometry import rotation_error_deg, translation_error
from locnerf.render.camera import PinholeIntrinsics


@dataclass(frozen=True)
class View:
    """One trial's input: a real image (H, W, 3), its true pose (4, 4) float64 and where it came from;
    ``depth``: the frame's depth image for RGB-D data sets (None otherwise)."""

    frame: int
    name: str
    truth: torch.Tensor
    image: torch.Tensor
    held_out: bool
    offset: torch.Tensor | None = None
    logged: LoggedTrial | None = None
    depth: DepthObservation | None = None


def frame_depth(posed: PosedImages, position: int) -> DepthObservation | None:
    """The depth image of frame ``position`` of ``posed`` (map units, its own camera), None for colour-only data."""
    if posed.depths is None or posed.depth_intrinsics is None:
        return None
    return DepthObservation(posed.depths[position], posed.depth_intrinsics, posed.T_cam_depth)


def logged_views(posed: PosedImages, trials: list[LoggedTrial], held_out: set[int]) -> list[View]:
    """Views for logged trials; ``posed`` must hold every frame (``split="all"``).

    Raises:
        DatasetError: if a logged frame is missing or its logged truth disagrees with the reader's.
    """
    views = []
    for trial in trials:
        if trial.frame not in posed.indices:
            raise DatasetError(f"logged frame {trial.frame} of {trial.scene} is not among the {len(posed)} images read from {posed.source}")
        position = posed.indices.index(trial.frame)
        truth = posed.T_world_cam[position].double()
        gap = float(translation_error(truth, trial.truth)) + float(rotation_error_deg(truth, trial.truth)) / 180.0
        if gap > 1e-3:
            raise DatasetError(f"frame {trial.frame}: logged ground truth differs from the reader's pose (gap {gap:.2e}); wrong data set or normalisation?")
        views.append(
            View(
                trial.frame,
                posed.names[position],
                truth,
                posed.images[position],
                trial.frame in held_out,
                trial.translation_offset,
                trial,
                frame_depth(posed, position),
            )
        )
    return views


def seeded_views(posed: PosedImages, count: int, generator: torch.Generator, held_out: set[int]) -> list[View]:
    """``count`` views of frames drawn uniformly (with replacement) from ``posed``."""
    positions = torch.randint(len(posed), (count,), generator=generator).tolist()
    return [
        View(posed.indices[p], posed.names[p], posed.T_world_cam[p].double(), posed.images[p], posed.indices[p] in held_out, depth=frame_depth(posed, p))
        for p in positions
    ]


def run_views(views: list[View], radiance_map: RadianceMap, intrinsics: PinholeIntrinsics, localizer: Localizer, config: TrialConfig) -> list[TrialResult]:
    """One trial per view seen by the camera ``intrinsics``; logged views start at the logged offset; a view's
    depth image is used when the localizer's ``measurement.depth`` is set."""
    return [
        run_trial(
            view.image.to(radiance_map.device),
            intrinsics,
            view.truth,
            radiance_map.render_rays,
            radiance_map.samples_per_ray,
            localizer,
            config,
            view.offset,
            surface_renderer(radiance_map),
            view.depth,
            surface_distance_of(radiance_map),
        )
        for view in views
    ]


def view_in_frame(view: View, move: Callable[[torch.Tensor], torch.Tensor]) -> View:
    """``view`` in another map frame; ``move`` takes poses (..., 4, 4) float64 there (a similarity,
    :func:`locnerf.data.posed_images.frame_change`). The truth moves; the start's translation offset becomes the
    moved displacement from the truth's position to that plus the offset (rotated and scaled with the frame); the
    logged trial stays in its own frame (the original's figures are scored against its own truth).

    Raises:
        LocnerfInputError: for a view with a depth image (its depths would need the new frame's units).
    """
    if view.depth is not None:
        raise LocnerfInputError(f"frame {view.frame}: a view with a depth image cannot be moved into another map frame (expected colour only)")
    truth = move(view.truth.double())
    offset = None
    if view.offset is not None:
        shifted = view.truth.double().clone()
        shifted[:3, 3] += view.offset.double()
        offset = move(shifted)[:3, 3] - truth[:3, 3]
    return replace(view, truth=truth, offset=offset)


def in_truth_units(result: TrialResult, units: float) -> TrialResult:
    """``result`` with its translation errors divided by ``units`` (map units per unit of the ground truth's frame:
    an SfM map aligned by ``locnerf map align`` has its own); ``result`` itself when ``units`` is 1."""
    if units == 1.0:
        return result
    return replace(result, translation_error=result.translation_error / units, history_translation=[e / units for e in result.history_translation])


Curve = tuple[list[int], list[float], list[float]]
"""One run's (cumulative rays rendered, translation errors, rotation errors in degrees), aligned."""


def result_curve(result: TrialResult) -> Curve:
    """Our trial's error curve against rays rendered."""
    return result.history_rays, result.history_translation, result.history_rotation_deg


def logged_curve(run: LoggedRun, truth: torch.Tensor) -> Curve:
    """A logged run's error curve against rays rendered.

    Raises:
        DatasetError: if the run logged no forward passes.
    """
    if run.rays is None:
        raise DatasetError("logged run without forward passes: expected a *_forward_passes.npy file or a known cost per slot")
    t_err, r_err = run.errors(truth)
    return run.rays.tolist(), t_err.tolist(), r_err.tolist()


def _original(run: LoggedRun | None, truth: torch.Tensor) -> dict | None:
    """The final figures of a logged run and its error history, JSON-ready."""
    if run is None:
        return None
    t_err, r_err = run.errors(truth)
    passes = int(run.forward_passes[-1]) if run.forward_passes is not None else None
    return {
        "translation_error": float(t_err[-1]),
        "rotation_error_deg": float(r_err[-1]),
        "success": bool(t_err[-1] < SUCCESS_TRANSLATION and r_err[-1] < SUCCESS_ROTATION_DEG),
        "forward_passes": passes,
        "history": {
            "forward_passes": run.forward_passes.tolist() if run.forward_passes is not None else None,
            "rays": run.rays.tolist() if run.rays is not None else None,
            "translation_error": t_err.tolist(),
            "rotation_error_deg": r_err.tolist(),
        },
    }


def trial_record(view: View, result: TrialResult) -> dict:
    """JSON-ready record of one trial, with the original's logged figures for the same start. ``estimate`` and
    ``truth`` are (4, 4) camera-to-world poses in the map's frame and units (OpenGL camera axes): where the trial
    ended and where it should have, for looking at a failure in the map itself (``estimate`` None: no final pose)."""
    record = {
        "frame": view.frame,
        "name": view.name,
        "held_out": view.held_out,
        "start": "logged" if view.logged else "seeded",
        "translation_error": result.translation_error,
        "rotation_error_deg": result.rotation_error_deg,
        "success": result.success,
        "seconds": result.seconds,
        "forward_passes": result.forward_passes,
        "rays": result.rays,
        "estimate": None if result.final_pose is None else result.final_pose.double().cpu().tolist(),
        "truth": view.truth.double().cpu().tolist(),
        "history": {
            "forward_passes": result.history_forward_passes,
            "rays": result.history_rays,
            "seconds": result.history_seconds,
            "translation_error": result.history_translation,
            "rotation_error_deg": result.history_rotation_deg,
        },
    }
    if view.logged is not None:
        record["original_locnerf"] = _original(view.logged.locnerf, view.logged.truth)
        record["original_inerf"] = _original(view.logged.inerf, view.logged.truth)
    return record


def totals(records: list[dict]) -> dict:
    """Success rate and median errors over records, overall and by subset."""

    def summary(subset: list[dict]) -> dict | None:
        if not subset:
            return None
        return {
            "trials": len(subset),
            "success_rate": sum(r["success"] for r in subset) / len(subset),
            "median_translation_error": statistics.median(r["translation_error"] for r in subset),
            "median_rotation_error_deg": statistics.median(r["rotation_error_deg"] for r in subset),
            "mean_seconds_per_trial": statistics.fmean(r["seconds"] for r in subset),
            "max_seconds_per_trial": max(r["seconds"] for r in subset),
        }

    logged = [r for r in records if r["start"] == "logged"]
    result = {
        "all": summary(records),
        "held_out_views": summary([r for r in records if r["held_out"]]),
        "training_views": summary([r for r in records if not r["held_out"]]),
        "logged_starts": summary(logged),
    }
    for key in ("original_locnerf", "original_inerf"):
        finals = [r[key] for r in logged if r.get(key)]
        if finals:
            result[f"{key}_on_logged_starts"] = {
                "trials": len(finals),
                "success_rate": sum(f["success"] for f in finals) / len(finals),
                "median_translation_error": statistics.median(f["translation_error"] for f in finals),
                "median_rotation_error_deg": statistics.median(f["rotation_error_deg"] for f in finals),
            }
    return result


def _latest_within(costs: list[int], budget: int) -> int | None:
    """Index of the last estimate whose cumulative cost fits ``budget``; None if none does."""
    index = bisect.bisect_right(costs, budget) - 1
    return index if index >= 0 else None


def success_by_budget(curves: list[Curve], budgets: list[int]) -> list[float]:
    """Fraction of runs whose latest estimate within each budget (rays rendered) is a success.

    Args:
        curves: per run (cumulative cost ascending, translation errors, rotation errors).
        budgets: cost budgets in the curves' unit, ascending.
    """
    rates = []
    for budget in budgets:
        hits = 0
        for costs, t_err, r_err in curves:
            index = _latest_within(costs, budget)
            if index is not None and t_err[index] < SUCCESS_TRANSLATION and r_err[index] < SUCCESS_ROTATION_DEG:
                hits += 1
        rates.append(hits / len(curves) if curves else 0.0)
    return rates


def mean_error_by_budget(curves: list[Curve], budgets: list[int]) -> tuple[list[float], list[float]]:
    """Mean translation and rotation error of the runs' latest estimates within each budget.

    Every run must have an estimate within the smallest budget (its start, at 0 cost, counts).

    Raises:
        ValueError: if a run has no estimate within some budget.
    """
    translation, rotation = [], []
    for budget in budgets:
        latest = [(t_err, r_err, _latest_within(costs, budget)) for costs, t_err, r_err in curves]
        if any(index is None for _, _, index in latest):
            raise ValueError(f"budget {budget}: a run has no estimate within it; expected every curve to start at or below the smallest budget")
        translation.append(statistics.fmean(t_err[index] for t_err, _, index in latest))
        rotation.append(statistics.fmean(r_err[index] for _, r_err, index in latest))
    return translation, rotation
