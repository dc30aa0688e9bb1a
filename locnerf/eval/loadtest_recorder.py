"""What a load test observes on the bus, and the figures it reports.

The observer subscribes to the same keys as the services (odometry, images, update requests and
results, poses, status) and stamps each arrival with its own monotonic clock. Every figure below is
computed from those arrivals over a measurement window ``[start, end]``; answers to messages of the
window (a pose for an odometry stamp, a result for a request shard) are accepted after ``end``, so
the caller keeps observing a little longer before calling :meth:`LoadRecorder.report`: until
:meth:`LoadRecorder.unanswered` is 0, or the filter's ``update_timeout`` has passed.

Lost messages are counted, not estimated:

* ``odometry``: gaps in the odometry stamps (they are ``k / odometry_rate``);
* ``images``: gaps in the image stamps (``k / camera_rate``);
* ``poses``: odometry stamps of the window without a pose of the same stamp;
* ``results``: request shards of the window without a result (keep observing at least the
  filter's ``update_timeout`` after the window, so that a late answer is not taken for a lost one);
* ``observer``: arrivals the observer's own inbox had to drop.

Updates the filter abandoned (its ``updates_timed_out`` counter) are reported beside, not added:
an abandoned shard without an answer is already a lost result, and one answered late was not lost.

``pose_jitter`` is ``|interval − 1/odometry_rate|`` between consecutive poses as they arrive;
``odometry_jitter`` is the same for the odometry arriving from the source, so that jitter the
source already has (its pacing on a busy machine) is told apart from jitter the filter adds.

Frames the filter skips because a newer one arrived (newest-only, by design) are ``dropped_frames``:
images of the window minus updates started in the window; ``images_replaced`` is the filter's own
count of them (its status counter over the window), which needs no image observed.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from locnerf.messages.codec import decode, decode_image
from locnerf.messages.schemas import FilterStatus, Odometry, PoseEstimate, UpdateRequest, UpdateResult

KINDS = ("odometry", "image", "request", "result", "pose", "status")


def _percentile_ms(seconds: list[float], q: float) -> float | None:
    """The ``q``-th percentile of ``seconds`` in milliseconds (None when empty)."""
    return round(1000.0 * float(np.percentile(seconds, q)), 2) if seconds else None


def _stamp_gaps(stamps: list[float], rate: float) -> int:
    """Missing stamps in a series that should be ``k / rate``: expected count minus seen count."""
    if len(stamps) < 2:
        return 0
    ordered = sorted(set(stamps))
    expected = round((ordered[-1] - ordered[0]) * rate) + 1
    return max(0, expected - len(ordered))


@dataclass
class LoadRecorder:
    """Arrival times of every observed message.

    Args:
        odometry_rate: odometry messages per second of the stream (the pose rate it should give).
        camera_rate: camera frames per second of the stream.
    """

    odometry_rate: float
    camera_rate: float
    odometry: dict[float, float] = field(default_factory=dict)
    images: dict[float, float] = field(default_factory=dict)
    poses: dict[float, float] = field(default_factory=dict)
    request_shards: dict[tuple[str, int], float] = field(default_factory=dict)
    results: dict[tuple[str, int], float] = field(default_factory=dict)
    worker_seconds: list[float] = field(default_factory=list)
    statuses: list[tuple[float, FilterStatus]] = field(default_factory=list)

    def observe(self, kind: str, payload: bytes, at: float) -> None:
        """Record one message of ``kind`` (one of ``KINDS``) that arrived at ``at`` (monotonic s).

        Raises:
            ValueError: ``kind`` is not one of ``KINDS``.
            locnerf.messages.codec.DecodeError: the payload is not a valid message of that kind.
        """
        if kind == "odometry":
            self.odometry.setdefault(decode(payload, Odometry).stamp, at)
        elif kind == "image":
            self.images.setdefault(decode_image(payload)[0].stamp, at)
        elif kind == "pose":
            self.poses.setdefault(decode(payload, PoseEstimate).stamp, at)
        elif kind == "request":
            request = decode(payload, UpdateRequest)
            self.request_shards.setdefault((request.request_id, request.shard), at)
        elif kind == "result":
            result = decode(payload, UpdateResult)
            if (result.request_id, result.shard) not in self.results:
                self.results[(result.request_id, result.shard)] = at
                self.worker_seconds.append(result.compute_seconds)
        elif kind == "status":
            self.statuses.append((at, decode(payload, FilterStatus)))
        else:
            raise ValueError(f"message kind {kind!r}: expected one of {KINDS}")

    def _updates(self) -> dict[str, tuple[float, float | None]]:
        """request id -> (first shard sent, last shard answered or None when incomplete)."""
        shards: dict[str, list[tuple[int, float]]] = defaultdict(list)
        for (request_id, shard), at in self.request_shards.items():
            shards[request_id].append((shard, at))
        updates = {}
        for request_id, sent in shards.items():
            answers = [self.results.get((request_id, shard)) for shard, _ in sent]
            done = None if any(a is None for a in answers) else max(answers)
            updates[request_id] = (min(at for _, at in sent), done)
        return updates

    def _poses_missing(self, start: float, end: float) -> int:
        """Odometry stamps that arrived in ``[start, end]`` without a pose of the same stamp (yet)."""
        return sum(1 for stamp, at in self.odometry.items() if start <= at <= end and stamp not in self.poses)

    def _results_missing(self, start: float, end: float) -> int:
        """Request shards that arrived in ``[start, end]`` without a result (yet)."""
        return sum(1 for key, at in self.request_shards.items() if start <= at <= end and key not in self.results)

    def unanswered(self, start: float, end: float) -> int:
        """Messages of the window ``[start, end]`` still waiting for their answer (a pose, a result): the
        observer can stop waiting after the window once this is 0."""
        return self._poses_missing(start, end) + self._results_missing(start, end)

    def _status_delta(self, name: str, start: float, end: float) -> int:
        """Growth of a filter status counter between the last status before ``start`` and the last before ``end``."""
        inside = [s.counters.get(name, 0) for at, s in self.statuses if at <= end]
        before = [s.counters.get(name, 0) for at, s in self.statuses if at <= start]
        if not inside:
            return 0
        return inside[-1] - (before[-1] if before else 0)

    def report(self, start: float, end: float, observer_drops: int = 0) -> dict[str, object]:
        """The figures of the window ``[start, end]`` (monotonic seconds of the observer).

        Raises:
            ValueError: ``end`` is not after ``start``.
        """
        window = end - start
        if window <= 0:
            raise ValueError(f"measurement window [{start}, {end}]: expected end after start")

        def inside(at: float) -> bool:
            return start <= at <= end

        updates = self._updates()
        started = {rid: span for rid, span in updates.items() if inside(span[0])}
        completed = [done for _, done in updates.values() if done is not None and inside(done)]
        latencies = [done - sent for sent, done in started.values() if done is not None]
        pose_times = sorted(at for at in self.poses.values() if inside(at))
        intervals = list(np.diff(pose_times)) if len(pose_times) > 1 else []
        jitter = [abs(i - 1.0 / self.odometry_rate) for i in intervals]
        odometry_in = {stamp: at for stamp, at in self.odometry.items() if inside(at)}
        odometry_times = sorted(odometry_in.values())
        odometry_jitter = [abs(i - 1.0 / self.odometry_rate) for i in np.diff(odometry_times)] if len(odometry_times) > 1 else []
        end_to_end = [self.poses[stamp] - at for stamp, at in odometry_in.items() if stamp in self.poses]
        images_in = [stamp for stamp, at in self.images.items() if inside(at)]
        lost = {
            "odometry": _stamp_gaps(list(odometry_in), self.odometry_rate),
            "images": _stamp_gaps(images_in, self.camera_rate),
            "poses": self._poses_missing(start, end),
            "results": self._results_missing(start, end),
            "observer": observer_drops,
        }
        return {
            "window_s": round(window, 3),
            "update_hz": round(len(completed) / window, 3),
            "updates_started": len(started),
            "updates_completed": len(completed),
            "update_latency_p50_ms": _percentile_ms(latencies, 50),
            "update_latency_p95_ms": _percentile_ms(latencies, 95),
            "update_latency_p99_ms": _percentile_ms(latencies, 99),
            "worker_compute_p50_ms": _percentile_ms(self.worker_seconds, 50),
            "pose_rate_hz": round(len(pose_times) / window, 3),
            "pose_interval_p99_ms": _percentile_ms(intervals, 99),
            "pose_jitter_p50_ms": _percentile_ms(jitter, 50),
            "pose_jitter_p99_ms": _percentile_ms(jitter, 99),
            "odometry_jitter_p99_ms": _percentile_ms(odometry_jitter, 99),
            "end_to_end_latency_p50_ms": _percentile_ms(end_to_end, 50),
            "end_to_end_latency_p99_ms": _percentile_ms(end_to_end, 99),
            "camera_frames": len(images_in),
            "dropped_frames": max(0, len(images_in) - len(started)),
            "lost_messages": sum(lost.values()),
            "lost_detail": lost,
            "odometry_messages": len(odometry_in),
            "images_replaced": self._status_delta("images_replaced", start, end),
            "updates_timed_out": self._status_delta("updates_timed_out", start, end),
            "stale_results": self._status_delta("stale_results", start, end),
        }
