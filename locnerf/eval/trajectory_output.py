"""A tracking run's trajectories in the field's format, and the drift of its odometry.

:func:`write_run_trajectories` writes, next to a run's JSON report, three TUM files in metres in the
map's data-set frame: ``reference.txt`` (the ground truth at every scored stamp), ``estimate.txt``
(the filter's estimate at the stamps the headline scores: from convergence to the end of the
start phase), after a kidnapping ``estimate_after_kidnap.txt`` (the estimate from the kidnapping's stamp
to the end: the recovery, scored by ``evo_ape`` against ``reference.txt`` the same way) and ``odometry.txt`` (the odometry's camera poses at every stamp that had one, in the
odometry's own frame). Then ``evo_ape tum reference.txt estimate.txt`` (no alignment: estimate and
reference share the map's frame, as the headline does) reports, per stamp, the translation errors
whose median is the headline ``translation_median`` (``--pose_relation angle_deg``: the rotation
errors). evo's median of an even count is the mean of the two middle values; the headline's is the
lower one.

:func:`odometry_drift` scores the odometry alone, the way odometry is usually reported: aligned to
the ground truth at its first pose (``T_align = T_truth(0) · T_odom(0)⁻¹``), the absolute error at
every later pose (APE), and the relative error of each step between consecutive poses summed over
the ground truth's path length (RPE per metre travelled).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from locnerf.data.trajectory_files import write_tum
from locnerf.eval.tracking import ConvergenceConfig, TrackingRecord, settle_tick
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import relative_pose, rotation_error_deg, translation_error
from locnerf.geometry.se3 import pose_inverse

REFERENCE, ESTIMATE, ESTIMATE_AFTER_KIDNAP, ODOMETRY = "reference.txt", "estimate.txt", "estimate_after_kidnap.txt", "odometry.txt"


def write_run_trajectories(
    folder: Path,
    record: TrackingRecord,
    normalization: MapNormalization,
    criterion: ConvergenceConfig,
    odometry_stamps: torch.Tensor,
    odometry_poses: torch.Tensor,
) -> dict[str, str]:
    """Write ``reference.txt``, ``estimate.txt`` and ``odometry.txt`` into ``folder`` (see the module docstring).

    Args:
        record: a run with ``estimates`` and ``truths`` (map units).
        odometry_stamps: (J,) seconds of the odometry poses.
        odometry_poses: (J, 4, 4) float64 ``T_odom_cam``, metres.
    Returns:
        name -> path of each file written (``estimate`` is absent when the run never converged,
        ``estimate_after_kidnap`` without a kidnapping).
    Raises:
        ValueError: a record without poses.
    """
    if record.estimates is None or record.truths is None:
        raise ValueError("the tracking record kept no poses: expected estimates and truths to write trajectories")
    folder.mkdir(parents=True, exist_ok=True)
    stamps = record.stamps.double()
    written = {"reference": str(write_tum(folder / REFERENCE, stamps, normalization.map_to_metric(record.truths)))}
    end = record.kidnap_tick if record.kidnap_tick is not None else len(stamps)
    settled = settle_tick(record, 0, end, criterion)
    if settled is not None:
        estimates = normalization.map_to_metric(record.estimates[settled:end])
        written["estimate"] = str(write_tum(folder / ESTIMATE, stamps[settled:end], estimates))
    if record.kidnap_tick is not None:
        after = normalization.map_to_metric(record.estimates[end:])
        written["estimate_after_kidnap"] = str(write_tum(folder / ESTIMATE_AFTER_KIDNAP, stamps[end:], after))
    if len(odometry_stamps):
        written["odometry"] = str(write_tum(folder / ODOMETRY, odometry_stamps.double(), odometry_poses.double()))
    return written


def odometry_drift(stamps: torch.Tensor, odometry: torch.Tensor, valid: torch.Tensor, truth: torch.Tensor) -> dict[str, Any]:
    """Drift of the odometry against the ground truth (see the module docstring).

    Args:
        stamps: (K,) seconds.
        odometry: (K, 4, 4) float64 ``T_odom_cam``, metres (ignored where not ``valid``).
        valid: (K,) bool.
        truth: (K, 4, 4) float64 true ``T_world_cam``, metres.
    Returns:
        APE (translation m, rotation °) median / final / max over the valid poses, RPE per metre
        (m and ° per metre of the truth's path), the path length, and the APE series.
    Raises:
        ValueError: fewer than two valid poses.
    """
    index = torch.nonzero(valid).reshape(-1)
    if len(index) < 2:
        raise ValueError(f"odometry drift: {len(index)} valid poses, expected at least 2")
    poses, truths = odometry[index].double(), truth[index].double()
    aligned = truth[index[0]] @ pose_inverse(poses[0]) @ poses
    ape_t, ape_r = translation_error(aligned, truths), rotation_error_deg(aligned, truths)
    step_odometry, step_truth = relative_pose(poses[:-1], poses[1:]), relative_pose(truths[:-1], truths[1:])
    rpe_t, rpe_r = translation_error(step_odometry, step_truth), rotation_error_deg(step_odometry, step_truth)
    path = float((truth[1:, :3, 3] - truth[:-1, :3, 3]).norm(dim=-1).sum())
    return {
        "poses": len(index),
        "gaps": int(len(valid) - len(index)),
        "path_length_m": path,
        "ape_translation_median": float(ape_t.median()),
        "ape_translation_final": float(ape_t[-1]),
        "ape_translation_max": float(ape_t.max()),
        "ape_rotation_median_deg": float(ape_r.median()),
        "ape_rotation_final_deg": float(ape_r[-1]),
        "ape_rotation_max_deg": float(ape_r.max()),
        "rpe_translation_per_m": float(rpe_t.sum()) / path if path > 0 else None,
        "rpe_rotation_deg_per_m": float(rpe_r.sum()) / path if path > 0 else None,
        "series": {"stamps": stamps[index].tolist(), "ape_translation": ape_t.tolist(), "ape_rotation_deg": ape_r.tolist()},
    }
