"""Figures in the style of the paper, written as PNG files (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import torch  # noqa: E402

from locnerf.eval.single_image import SUCCESS_ROTATION_DEG, SUCCESS_TRANSLATION, TrialResult  # noqa: E402


def save_figure(figure: plt.Figure, path: Path, title: str) -> Path:
    """Title, lay out and write ``figure`` to ``path`` (PNG, 100 dpi), then release it."""
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


RAYS_LABEL = "rays rendered (thousands; the paper's forward passes ÷ 128)"


def plot_error_curves(results: list[TrialResult], path: Path, title: str, against: Literal["rays", "seconds"] = "rays") -> Path:
    """Translation and rotation error of every trial against rays rendered or wall time (paper Fig. 3 style)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    for result in results:
        abscissa = [r / 1e3 for r in result.history_rays] if against == "rays" else result.history_seconds
        ax_t.plot(abscissa, result.history_translation, alpha=0.7)
        ax_r.plot(abscissa, result.history_rotation_deg, alpha=0.7)
    for axis, threshold, label in ((ax_t, SUCCESS_TRANSLATION, "translation error (map units)"), (ax_r, SUCCESS_ROTATION_DEG, "rotation error (deg)")):
        axis.axhline(threshold, color="k", linestyle="--", linewidth=1, label="success threshold")
        axis.set_yscale("log")
        axis.set_xlabel(RAYS_LABEL if against == "rays" else "wall time (s)")
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend()
    return save_figure(figure, path, title)


def plot_mean_error_against_rays(series: dict[str, tuple[list[int], list[float], list[float]]], path: Path, title: str) -> Path:
    """Mean translation and rotation error against rays rendered for several methods (paper Fig. 2 style).

    Args:
        series: method name -> (ray budgets, mean translation error, mean rotation error in
            degrees at each budget).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    for name, (budgets, translation, rotation) in series.items():
        thousands = [b / 1e3 for b in budgets]
        ax_t.plot(thousands, translation, marker="o", markersize=3, label=name)
        ax_r.plot(thousands, rotation, marker="o", markersize=3, label=name)
    for axis, threshold, label in (
        (ax_t, SUCCESS_TRANSLATION, "mean translation error (map units)"),
        (ax_r, SUCCESS_ROTATION_DEG, "mean rotation error (deg)"),
    ):
        axis.axhline(threshold, color="k", linestyle="--", linewidth=1, label="success threshold")
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xlabel(RAYS_LABEL)
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=8)
    return save_figure(figure, path, title)


def plot_success_against_rays(series: dict[str, tuple[list[int], list[float]]], path: Path, title: str) -> Path:
    """Success ratio against rays rendered for several methods (paper Fig. 2 style).

    Args:
        series: method name -> (ray budgets, success ratio at each budget).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, axis = plt.subplots(figsize=(6, 4))
    for name, (budgets, rates) in series.items():
        axis.plot([b / 1e3 for b in budgets], rates, marker="o", markersize=3, label=name)
    axis.set_xscale("log")
    axis.set_xlabel(RAYS_LABEL)
    axis.set_ylabel(f"success ratio (< {SUCCESS_TRANSLATION} units and < {SUCCESS_ROTATION_DEG:g}°)")
    axis.set_ylim(-0.02, 1.02)
    axis.grid(True, alpha=0.3)
    axis.legend()
    return save_figure(figure, path, title)


def plot_images_beside_renders(
    panels: list[tuple[str, torch.Tensor, torch.Tensor]], path: Path, title: str, render_heading: str = "map at the estimate"
) -> Path:
    """Camera images beside the map rendered at a pose (by default the estimate), one row each (paper Fig. 6 style).

    Args:
        panels: (label, camera image (H, W, 3), rendering (H, W, 3)), colours in [0, 1].
        render_heading: title of the rendering column.
    """
    if not panels:
        raise ValueError("no panels to plot: expected at least one (label, image, rendering)")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure, axes = plt.subplots(len(panels), 2, figsize=(7, 3.2 * len(panels)), squeeze=False)
    for row, (label, image, rendering) in zip(axes, panels):
        for axis, picture, heading in ((row[0], image, f"camera: {label}"), (row[1], rendering, render_heading)):
            axis.imshow(picture.clamp(0, 1).cpu().numpy())
            axis.set_title(heading, fontsize=9)
            axis.axis("off")
    return save_figure(figure, path, title)
