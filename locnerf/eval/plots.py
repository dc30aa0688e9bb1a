"""Figures in the style of the paper, written as PNG files (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)

from locnerf.eval.single_image import SUCCESS_ROTATION_DEG, SUCCESS_TRANSLATION, TrialResult  # noqa: E402


def plot_error_curves(results: list[TrialResult], path: Path, title: str) -> Path:
    """Translation and rotation error of every trial against forward passes (paper Fig. 3 style)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    for result in results:
        passes = [p / 1e6 for p in result.history_forward_passes]
        ax_t.plot(passes, result.history_translation, alpha=0.7)
        ax_r.plot(passes, result.history_rotation_deg, alpha=0.7)
    for axis, threshold, label in ((ax_t, SUCCESS_TRANSLATION, "translation error (map units)"), (ax_r, SUCCESS_ROTATION_DEG, "rotation error (deg)")):
        axis.axhline(threshold, color="k", linestyle="--", linewidth=1, label="success threshold")
        axis.set_yscale("log")
        axis.set_xlabel("forward passes (millions)")
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend()
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def plot_success_against_passes(series: dict[str, tuple[list[int], list[float]]], path: Path, title: str) -> Path:
    """Success ratio against forward passes for several methods (paper Fig. 2 style).

    Args:
        series: method name -> (forward-pass budgets, success ratio at each budget).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, axis = plt.subplots(figsize=(6, 4))
    for name, (budgets, rates) in series.items():
        axis.plot([b / 1e6 for b in budgets], rates, marker="o", markersize=3, label=name)
    axis.set_xscale("log")
    axis.set_xlabel("forward passes (millions, log scale)")
    axis.set_ylabel(f"success ratio (< {SUCCESS_TRANSLATION} units and < {SUCCESS_ROTATION_DEG:g}°)")
    axis.set_ylim(-0.02, 1.02)
    axis.grid(True, alpha=0.3)
    axis.legend()
    axis.set_title(title)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
