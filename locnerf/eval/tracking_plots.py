"""Tracking error over time (paper Fig. 5 style), written as a PNG file."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt

from locnerf.eval.plots import save_figure
from locnerf.eval.tracking import ConvergenceConfig, TrackingRecord


def plot_tracking_errors(record: TrackingRecord, converged_at: list[float], criterion: ConvergenceConfig, path: Path, title: str) -> Path:
    """Translation and rotation error against time, with convergence and the kidnapping marked.

    Args:
        converged_at: stamps (seconds) at which the filter converged / recovered.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    stamps = record.stamps.tolist()
    figure, (ax_t, ax_r) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    panels = (
        (ax_t, record.translation_error.tolist(), criterion.translation, "translation error (map units)"),
        (ax_r, record.rotation_error_deg.tolist(), criterion.rotation_deg, "rotation error (deg)"),
    )
    for axis, errors, threshold, label in panels:
        axis.plot(stamps, errors, linewidth=1.2, label="estimate")
        axis.axhline(threshold, color="k", linestyle="--", linewidth=1, label="convergence threshold")
        for index, stamp in enumerate(converged_at):
            axis.axvline(stamp, color="tab:green", linewidth=1, label="converged" if index == 0 else None)
        if record.kidnap_tick is not None:
            axis.axvline(stamps[record.kidnap_tick], color="tab:red", linewidth=1.5, label="kidnapping")
        axis.set_yscale("log")
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    ax_t.legend(loc="upper right", fontsize=8)
    ax_r.set_xlabel("time (s)")
    return save_figure(figure, path, title)


def plot_error_and_drift(record: TrackingRecord, drift: dict[str, list[float]], path: Path, title: str) -> Path:
    """The filter's error beside its odometry's own drift, both against time: translation (top) and rotation (bottom).

    Args:
        record: the run (errors in map units, degrees).
        drift: ``stamps``, ``ape_translation`` (m) and ``ape_rotation_deg`` of the odometry aligned at its
            first pose (the ``series`` of :func:`locnerf.eval.trajectory_output.odometry_drift`).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_t, ax_r) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    stamps = record.stamps.tolist()
    for axis, errors, odometry, label in (
        (ax_t, record.translation_error.tolist(), drift["ape_translation"], "translation error (m)"),
        (ax_r, record.rotation_error_deg.tolist(), drift["ape_rotation_deg"], "rotation error (deg)"),
    ):
        # The first pose is aligned exactly (error 0): left out of the log scale.
        axis.plot(drift["stamps"][1:], odometry[1:], color="tab:orange", linewidth=1.2, label="odometry alone (aligned at its first pose)")
        axis.plot(stamps, errors, color="tab:blue", linewidth=1.2, label="locnerf estimate")
        axis.set_yscale("log")
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    ax_t.legend(loc="upper left", fontsize=8)
    ax_r.set_xlabel("time (s)")
    return save_figure(figure, path, title)
