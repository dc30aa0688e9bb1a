"""The load-test figures from hand-made arrivals: rates, latencies, jitter, losses."""

from __future__ import annotations

import numpy as np
import pytest

from locnerf.eval.loadtest_recorder import LoadRecorder
from locnerf.messages.codec import encode, encode_image
from locnerf.messages.schemas import ImageHeader, Odometry, PoseEstimate, UpdateRequest, UpdateResult
from locnerf.render.camera import PinholeIntrinsics

IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
ZERO6 = [[0.0] * 6 for _ in range(6)]
INTRINSICS = PinholeIntrinsics(fx=10.0, fy=10.0, cx=2.0, cy=2.0, width=4, height=4)


def odometry(stamp: float) -> bytes:
    return encode(Odometry(stamp=stamp, T_odom_body=IDENTITY))


def pose(stamp: float) -> bytes:
    estimate = PoseEstimate(
        stamp=stamp, T_world_cam=IDENTITY, covariance=ZERO6, particle_count=1, spread=0.0, effective_sample_size=1.0, mode="coarse", epoch=0
    )
    return encode(estimate)


def image(stamp: float) -> bytes:
    header = ImageHeader(stamp=stamp, encoding="rgb8", width=4, height=4, intrinsics=INTRINSICS)
    return encode_image(header, np.zeros((4, 4, 3), dtype=np.uint8))


def request(request_id: str, shard: int) -> bytes:
    message = UpdateRequest(
        request_id=request_id,
        shard=shard,
        map_checksum="ab" * 32,
        epoch=0,
        generation=0,
        ids=[0],
        poses=[sum(IDENTITY, [])],
        pixels=[[1.0, 1.0]],
        observed_rgb=[[0.0, 0.0, 0.0]],
        intrinsics=INTRINSICS,
    )
    return encode(message)


def result(request_id: str, shard: int) -> bytes:
    message = UpdateResult(request_id=request_id, shard=shard, worker_id="w", epoch=0, generation=0, ids=[0], log_likelihoods=[0.0], compute_seconds=0.01)
    return encode(message)


def steady_stream(recorder: LoadRecorder, seconds: float, skip_pose_at: set[int] = frozenset(), skip_odometry: set[int] = frozenset()) -> None:
    """Odometry at 10 Hz answered by a pose 5 ms later; a frame and a 2-shard update every 0.5 s (latency 40 ms)."""
    for k in range(int(seconds * 10)):
        stamp = k / 10
        if k not in skip_odometry:
            recorder.observe("odometry", odometry(stamp), stamp)
            if k not in skip_pose_at:
                recorder.observe("pose", pose(stamp), stamp + 0.005)
        if k % 5 == 0:
            recorder.observe("image", image(stamp), stamp)
            for shard in (0, 1):
                recorder.observe("request", request(f"u{k}", shard), stamp + 0.001)
                recorder.observe("result", result(f"u{k}", shard), stamp + 0.001 + 0.02 * (shard + 1))


def test_steady_stream_gives_its_rates_and_latencies():
    recorder = LoadRecorder(odometry_rate=10.0, camera_rate=2.0)
    steady_stream(recorder, 10.0)
    report = recorder.report(0.0, 10.0)
    assert report["pose_rate_hz"] == pytest.approx(10.0, abs=0.11)
    assert report["update_hz"] == pytest.approx(2.0, abs=0.11)
    assert report["update_latency_p50_ms"] == pytest.approx(40.0, abs=1e-6)
    assert report["update_latency_p99_ms"] == pytest.approx(40.0, abs=1e-6)
    assert report["end_to_end_latency_p99_ms"] == pytest.approx(5.0, abs=1e-6)
    assert report["pose_jitter_p99_ms"] == pytest.approx(0.0, abs=1e-6)
    assert report["odometry_jitter_p99_ms"] == pytest.approx(0.0, abs=1e-6)
    assert report["dropped_frames"] == 0
    assert report["lost_messages"] == 0


def test_missing_poses_odometry_and_results_are_lost_not_dropped():
    recorder = LoadRecorder(odometry_rate=10.0, camera_rate=2.0)
    steady_stream(recorder, 5.0, skip_pose_at={3, 7}, skip_odometry={20})
    recorder.observe("image", image(5.25), 5.25)  # a frame no update used: dropped by design
    recorder.observe("request", request("late", 0), 5.3)  # never answered
    report = recorder.report(0.0, 5.5, observer_drops=1)
    assert report["lost_detail"] == {"odometry": 1, "images": 0, "poses": 2, "results": 1, "observer": 1}
    assert report["lost_messages"] == 5
    assert report["dropped_frames"] == 0  # the unanswered update started on the extra frame
    # a pose missing twice shows up in the interval jitter: 200 ms instead of 100 ms.
    assert report["pose_interval_p99_ms"] == pytest.approx(200.0, abs=1.0)


def test_unanswered_counts_the_window_messages_still_waiting_until_their_answers_arrive():
    recorder = LoadRecorder(odometry_rate=10.0, camera_rate=2.0)
    steady_stream(recorder, 2.0)
    assert recorder.unanswered(0.0, 2.0) == 0
    recorder.observe("odometry", odometry(2.0), 2.0)
    recorder.observe("request", request("open", 0), 2.0)
    recorder.observe("request", request("open", 1), 2.0)
    recorder.observe("odometry", odometry(2.1), 2.1)  # after the window: not waited for
    assert recorder.unanswered(0.0, 2.0) == 3
    recorder.observe("pose", pose(2.0), 2.05)
    recorder.observe("result", result("open", 1), 2.06)
    assert recorder.unanswered(0.0, 2.0) == 1
    recorder.observe("result", result("open", 0), 2.5)
    assert recorder.unanswered(0.0, 2.0) == 0
    assert recorder.report(0.0, 2.0)["lost_messages"] == 0


def test_frames_beyond_the_updates_are_dropped_frames():
    recorder = LoadRecorder(odometry_rate=10.0, camera_rate=10.0)
    for k in range(10):
        recorder.observe("image", image(k / 10), k / 10)
    recorder.observe("request", request("only", 0), 0.01)
    recorder.observe("result", result("only", 0), 0.05)
    report = recorder.report(0.0, 1.0)
    assert report["dropped_frames"] == 9
    assert report["lost_messages"] == 0


def test_unknown_kind_and_empty_window_are_rejected():
    recorder = LoadRecorder(odometry_rate=10.0, camera_rate=2.0)
    with pytest.raises(ValueError, match="'gps'"):
        recorder.observe("gps", b"", 0.0)
    with pytest.raises(ValueError, match="expected end after start"):
        recorder.report(1.0, 1.0)
