"""Sweep results of ``locnerf loadtest``: a CSV row per case and a plot of rate and latency."""

from __future__ import annotations

import csv
from pathlib import Path

SWEEP_COLUMNS = (
    "workers",
    "particles",
    "pixels",
    "rays",
    "update_hz",
    "update_latency_p50_ms",
    "update_latency_p99_ms",
    "worker_compute_p50_ms",
    "pose_rate_hz",
    "pose_jitter_p99_ms",
    "end_to_end_latency_p99_ms",
    "dropped_frames",
    "lost_messages",
)


def write_sweep_csv(rows: list[dict[str, object]], path: Path) -> Path:
    """One line per case with ``SWEEP_COLUMNS`` (``rows`` are loadtest reports)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=SWEEP_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return path


def plot_sweep(rows: list[dict[str, object]], path: Path) -> Path:
    """Update rate and p50/p99 update latency against particles × pixels, one line per worker count and pixel count.

    ``rows`` are loadtest reports or the rows of a sweep CSV read back (numbers as text).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    figure, (ax_rate, ax_latency) = plt.subplots(1, 2, figsize=(11, 4.5))
    series = sorted({(int(r["workers"]), int(r["pixels"])) for r in rows})
    for workers, pixels in series:
        case = sorted((r for r in rows if int(r["workers"]) == workers and int(r["pixels"]) == pixels), key=lambda r: int(r["rays"]))
        rays = [int(r["rays"]) for r in case]
        label = f"{workers} worker{'s' if workers > 1 else ''}, {pixels} px"
        ax_rate.plot(rays, [float(r["update_hz"]) for r in case], "o-", label=label)
        p50 = [float(r["update_latency_p50_ms"] or "nan") for r in case]
        p99 = [float(r["update_latency_p99_ms"] or "nan") for r in case]
        (line,) = ax_latency.plot(rays, p50, "o-", label=f"{label} p50")
        ax_latency.plot(rays, p99, "x--", color=line.get_color(), label=f"{label} p99")
    ticks = sorted({int(r["rays"]) for r in rows})
    for axis, title in ((ax_rate, "update rate (Hz)"), (ax_latency, "update latency (ms)")):
        axis.set_xscale("log")
        axis.minorticks_off()
        axis.set_xticks(ticks, [f"{t / 1000:g}k" for t in ticks])
        axis.set_xlabel("particles × pixels (rays per update)")
        axis.set_title(title)
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=7)
    figure.suptitle("locnerf loadtest sweep (end to end through Zenoh)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path
