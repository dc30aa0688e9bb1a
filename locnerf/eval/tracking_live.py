"""Scoring a live tracking run: what was seen on the bus -> the offline report, plus measured rates.

``locnerf eval tracking --live`` records, with their wall-clock arrival times, the odometry the
ingest published, the ground truth, the filter's published poses and the update results. This
module turns that into the offline :class:`~locnerf.eval.tracking.TrackingRecord` (errors at every
published pose that has ground truth of the same stamp, in map units; updates placed at the newest
pose published before their result arrived), so convergence, after-convergence statistics and the
kidnap recovery are computed by exactly the offline code (:func:`~locnerf.eval.tracking.summarize_tracking`),
and measures the rates:

- ``realtime_factor``: sensor seconds per wall second of the odometry stream as it arrived
  (span of odometry stamps / span of their arrival times): 1.0 when the ingest kept pace;
- ``pose_realtime_factor``: the same for the filter's poses (below 1 when the filter falls behind);
- ``pose_hz``, ``update_hz``: published poses and completed updates per wall second, over the
  span of the poses;
- ``pose_latency_*_ms``: arrival of a pose minus arrival of the odometry of the same stamp;
- ``particles_median`` / ``_min`` / ``_max``: the filter's particle count over its poses;
- ``recoveries``, ``particles_injected``: how often kidnapping recovery fired and how many particles
  it injected, from the filter's last status (1 Hz; the run waits 3 s after the last sensor message).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Any

import torch

from locnerf.eval.tracking import BACK_ON_TRACK, ConvergenceConfig, TrackingRecord, error_series, summarize_tracking
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import rotation_error_deg, translation_error


@dataclass
class LiveObservations:
    """What the observer saw, each with its arrival time (monotonic seconds).

    Attributes:
        odometry: (stamp, arrival) of every odometry message.
        odometry_poses: its ``T_odom_body`` (4, 4) float64, metres, by stamp.
        truth: true ``T_world_cam`` (4, 4) float64, metric, by stamp.
        poses: (stamp, arrival, ``T_world_cam`` (4, 4) float64 metric) of every published pose.
        updates: arrival of the last shard of every update result, by request id.
        particle_counts: the filter's particle count with every published pose.
        filter_counters: the counters of the filter's last status (``recoveries``: times recovery fired).
        ingest_counters: the counters of the ingest's last status (its online odometry's, when it computes it).
    """

    odometry: list[tuple[float, float]] = field(default_factory=list)
    odometry_poses: dict[float, torch.Tensor] = field(default_factory=dict)
    truth: dict[float, torch.Tensor] = field(default_factory=dict)
    poses: list[tuple[float, float, torch.Tensor]] = field(default_factory=list)
    updates: dict[str, float] = field(default_factory=dict)
    particle_counts: list[int] = field(default_factory=list)
    filter_counters: dict[str, int] = field(default_factory=dict)
    ingest_counters: dict[str, int] = field(default_factory=dict)


def _span_rate(stamps: list[float], arrivals: list[float]) -> float | None:
    """Stamp span over arrival span (sensor seconds per wall second), None under two samples."""
    if len(stamps) < 2 or arrivals[-1] <= arrivals[0]:
        return None
    return (stamps[-1] - stamps[0]) / (arrivals[-1] - arrivals[0])


def live_record(observed: LiveObservations, normalization: MapNormalization, kidnap_at: float | None) -> TrackingRecord:
    """The offline record of a live run: errors (map units, degrees) at the scored poses.

    Raises:
        ValueError: no published pose had ground truth of its stamp.
    """
    scored = sorted((s, a, p) for s, a, p in observed.poses if s in observed.truth)
    if not scored:
        raise ValueError(f"none of the {len(observed.poses)} published poses had ground truth of its stamp: nothing to score")
    stamps = torch.tensor([s for s, _, _ in scored], dtype=torch.float64)
    estimates = normalization.metric_to_map(torch.stack([p for _, _, p in scored]))
    truths = normalization.metric_to_map(torch.stack([observed.truth[s] for s, _, _ in scored]))
    arrivals = [a for _, a, _ in scored]
    ticks = sorted(max(0, bisect.bisect_right(arrivals, arrival) - 1) for arrival in observed.updates.values())
    kidnap_tick = None
    if kidnap_at is not None:
        after = int(torch.searchsorted(stamps, torch.tensor([kidnap_at - 1e-9], dtype=torch.float64))[0])
        kidnap_tick = after if 0 < after < len(scored) else None
    return TrackingRecord(
        stamps=stamps,
        translation_error=translation_error(estimates, truths).double(),
        rotation_error_deg=rotation_error_deg(estimates, truths).double(),
        update_ticks=ticks,
        kidnap_tick=kidnap_tick,
        seconds=arrivals[-1] - arrivals[0],
        estimates=estimates.double(),
        truths=truths.double(),
    )


def live_rates(observed: LiveObservations) -> dict[str, Any]:
    """Measured rates and latencies of the run (see the module docstring)."""
    odometry = sorted(observed.odometry)
    poses = sorted((s, a) for s, a, _ in observed.poses)
    pose_arrivals = [a for _, a in poses]
    window = pose_arrivals[-1] - pose_arrivals[0] if len(poses) > 1 else 0.0
    odometry_arrival = dict(odometry)
    latencies = torch.tensor([a - odometry_arrival[s] for s, a in poses if s in odometry_arrival], dtype=torch.float64) * 1000
    in_window = sum(1 for arrival in observed.updates.values() if pose_arrivals and pose_arrivals[0] <= arrival <= pose_arrivals[-1])
    rates: dict[str, Any] = {
        "realtime_factor": _span_rate([s for s, _ in odometry], [a for _, a in odometry]),
        "pose_realtime_factor": _span_rate([s for s, _ in poses], pose_arrivals),
        "pose_hz": (len(poses) - 1) / window if window > 0 else None,
        "update_hz": in_window / window if window > 0 else None,
        "poses": len(poses),
        "updates": len(observed.updates),
        "odometry_messages": len(odometry),
    }
    if observed.particle_counts:
        counts = torch.tensor(observed.particle_counts, dtype=torch.float64)
        rates |= {"particles_median": float(counts.median()), "particles_min": int(counts.min()), "particles_max": int(counts.max())}
    if "recoveries" in observed.filter_counters:
        counters = observed.filter_counters
        rates |= {name: counters.get(name, 0) for name in ("recoveries", "particles_injected", "searches", "searches_moved", "drops_in_place")}
    if latencies.numel():
        rates |= {f"pose_latency_{name}_ms": float(torch.quantile(latencies, q)) for name, q in (("p50", 0.5), ("p95", 0.95), ("max", 1.0))}
    return rates


def live_summary(
    observed: LiveObservations,
    normalization: MapNormalization,
    kidnap_at: float | None,
    criterion: ConvergenceConfig,
    series: bool = False,
    back_on_track: ConvergenceConfig = BACK_ON_TRACK,
) -> dict[str, Any]:
    """The offline report of the run, its rates, and the headline figures at the top level:
    ``translation_median`` / ``rotation_median_deg`` after convergence, ``converged_after_s``
    (sensor seconds from the first scored pose), and the kidnap recovery when there was one (None where not reached;
    ``kidnap_back_on_track_s`` by the ``back_on_track`` criterion);
    with ``series``, also the error series of the scored poses (``series``, as the offline JSON report)."""
    record = live_record(observed, normalization, kidnap_at)
    summary = summarize_tracking(record, criterion, back_on_track)
    start = summary["start"]
    after = start.get("after_convergence", {})
    headline: dict[str, Any] = {
        "translation_median": after.get("translation_median"),
        "rotation_median_deg": after.get("rotation_median_deg"),
        "converged_after_s": start.get("seconds_to_converge"),
    }
    if kidnap_at is not None:
        kidnap = summary.get("kidnap", {})
        headline |= {
            "kidnap_recovery_updates": kidnap.get("updates_to_converge"),
            "kidnap_recovery_s": kidnap.get("seconds_to_converge"),
            "kidnap_back_on_track_s": kidnap.get("back_on_track_s"),
        }
    return headline | live_rates(observed) | summary | ({"series": error_series(record)} if series else {})
