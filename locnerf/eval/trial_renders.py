"""Which pose the map itself prefers for a trial's view: where the trial ended, or the ground truth.

A relocalization trial fails when its estimate ends more than 5 cm or 5° from the ground truth. Where the
ground truth disagrees with the poses the map was built from (a pose file that drifts between the capture
the map saw and the one it is tested on), a localizer that finds the map's best explanation of the image
fails by construction. Rendering the view from both poses tells the cases apart: a failure whose estimate
the map renders closer to the camera's image than the truth (higher PSNR and SSIM) ended where the map
puts the camera; one the truth renders better is the localizer's miss.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.errors import LocnerfInputError
from locnerf.render.image import RenderRays, render_image
from locnerf.train import psnr, ssim

TRUTH_TOLERANCE = 1e-5
"""Largest entry-wise difference (map units) between a report's truth and the view's pose read again."""


def _checked_pose(trial: dict, key: str) -> torch.Tensor:
    """A trial's (4, 4) float64 pose under ``key``, or a clear error naming the trial."""
    value = trial.get(key)
    if value is None:
        raise LocnerfInputError(f"trial {trial.get('name')!r}: no {key!r} pose (expected a report of locnerf eval single-image|global --json that records it)")
    pose = torch.tensor(value, dtype=torch.float64)
    if pose.shape != (4, 4) or not torch.isfinite(pose).all():
        raise LocnerfInputError(f"trial {trial.get('name')!r}: {key!r} is not a finite 4x4 matrix (shape {tuple(pose.shape)})")
    return pose


def read_trials_report(path: Path) -> list[dict]:
    """The ``trials`` of a ``locnerf eval single-image|global --json`` report, each with a finite 4×4 ``estimate``
    and ``truth`` (checked here, before a map is loaded).

    Raises:
        FileNotFoundError: no such file.
        LocnerfInputError: not JSON, no non-empty list of trials, or a trial without both poses.
    """
    if not path.is_file():
        raise FileNotFoundError(f"report {path}: no such file")
    try:
        report = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise LocnerfInputError(f"report {path}: not JSON ({error})") from error
    trials = report.get("trials") if isinstance(report, dict) else None
    if not isinstance(trials, list) or not trials or not all(isinstance(trial, dict) for trial in trials):
        raise LocnerfInputError(f"report {path}: expected a JSON object with a non-empty list of trials (locnerf eval single-image|global --json)")
    for trial in trials:
        for key in ("truth", "estimate"):
            _checked_pose(trial, key)
    return trials


def score_trial_renders(render_rays: RenderRays, views: PosedImages, trials: list[dict], device: torch.device | str = "cpu") -> dict[str, Any]:
    """PSNR and SSIM of each trial's camera image against the map rendered from its estimate and from its truth.

    Args:
        render_rays: the map's ray renderer; views: the data set's frames in the map's frame, on its camera
            (:func:`locnerf.data.colour_camera.read_on_map_camera`), among them every trial's view by name.
        trials: the ``trials`` of a ``locnerf eval single-image|global --json`` report on the same map
            (``estimate`` and ``truth``: (4, 4) camera-to-world, map frame).
        device: where the map renders.
    Returns:
        ``trials``: per trial its frame, name, success, errors, ``psnr_estimate``, ``psnr_truth`` (dB),
        ``ssim_estimate``, ``ssim_truth``; ``failures`` and ``successes``: the count, the median and range of
        PSNR(estimate) − PSNR(truth) and how many render better from the estimate (None when there are none).
    Raises:
        LocnerfInputError: a trial's view is not among ``views``, its truth is not the view's pose (a report of
            another map, data set or ground truth), or it records no estimate.
    """
    positions = {name: index for index, name in enumerate(views.names)}
    rows = []
    for trial in trials:
        position = positions.get(trial.get("name"))
        if position is None:
            raise LocnerfInputError(
                f"trial {trial.get('name')!r}: not a view of this split (expected one of {len(positions)} views such as {views.names[0]!r})"
            )
        truth, estimate = _checked_pose(trial, "truth"), _checked_pose(trial, "estimate")
        difference = float((truth - views.T_world_cam[position].double().cpu()).abs().max())
        if difference > TRUTH_TOLERANCE:
            raise LocnerfInputError(
                f"trial {trial['name']!r}: its truth is {difference:.3g} map units from the view's pose read now "
                "(expected the report of this map, data set and --poses)"
            )
        image = views.images[position]
        rendered = {
            key: render_image(render_rays, pose.to(device, torch.float32), views.intrinsics).cpu() for key, pose in (("estimate", estimate), ("truth", truth))
        }
        rows.append(
            {
                "frame": trial.get("frame"),
                "name": trial["name"],
                "success": bool(trial.get("success")),
                "translation_error": trial.get("translation_error"),
                "rotation_error_deg": trial.get("rotation_error_deg"),
                **{f"psnr_{key}": psnr(value, image) for key, value in rendered.items()},
                **{f"ssim_{key}": ssim(value, image) for key, value in rendered.items()},
            }
        )
    return {"trials": rows, "failures": _preference([r for r in rows if not r["success"]]), "successes": _preference([r for r in rows if r["success"]])}


def _preference(rows: list[dict]) -> dict[str, Any] | None:
    """How much better the map renders these trials' views from their estimates than from their truths."""
    if not rows:
        return None
    gains = [row["psnr_estimate"] - row["psnr_truth"] for row in rows]
    return {
        "trials": len(rows),
        "psnr_gain_median_db": statistics.median(gains),
        "psnr_gain_min_db": min(gains),
        "psnr_gain_max_db": max(gains),
        "estimate_renders_better": sum(gain > 0 for gain in gains),
    }
