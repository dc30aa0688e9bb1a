"""``locnerf loadtest --overload``, short: odometry and images 10× faster for a few seconds lose no odometry."""

from __future__ import annotations

from tests.loadtest.run_loadtest import run_loadtest


def test_overload_loses_no_odometry_and_replaces_images(tmp_path):
    # 150 Hz images against updates of 300 particles x 64 pixels (about 12-15 Hz on 2 cores, docs/PERFORMANCE.md):
    # the filter cannot take every image, so newest-only must replace some. (At 60 x 16 the filter took
    # 50 Hz images one by one on a quiet machine, and replaced none.) The simulator takes images at odometry
    # stamps, so the camera rate is at most the odometry rate (15 Hz); the removed world stream sent 300 Hz.
    report = run_loadtest(
        tmp_path, "--overload", "10", "--particles", "300", "--pixels", "64", "--camera-rate", "15", "--duration", "3", "--warmup", "1", "--memory-period", "1"
    )
    assert report["overload"] == 10.0 and report["lost_messages"] == 0, report["lost_detail"]
    # Every odometry message of the window (sent at 150 Hz) has its pose: lost_detail["poses"] == 0 above.
    assert report["odometry_messages"] > 0 and report["lost_detail"]["poses"] == 0
    assert report["images_replaced"] > 0 and report["camera_frames"] == 0  # images are counted by the filter, not observed
    filter_memory = report["processes"]["filter"]
    assert filter_memory["rss_start_mb"] <= filter_memory["rss_max_mb"] and filter_memory["rss_end_mb"] <= filter_memory["rss_max_mb"]
