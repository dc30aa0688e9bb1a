"""A short real load test through Zenoh (seconds): the report's structure and no lost messages."""

from __future__ import annotations

from locnerf_cli.loadtest import TABLE_ROWS, format_table
from tests.loadtest.run_loadtest import run_loadtest

ISSUE_KEYS = ("update_hz", "update_latency_p99_ms", "pose_rate_hz", "pose_jitter_p99_ms", "dropped_frames", "lost_messages")


def test_short_loadtest_reports_every_key_and_loses_nothing(tmp_path):
    report = run_loadtest(tmp_path, "--particles", "60", "--pixels", "16", "--camera-rate", "5", "--duration", "4", "--warmup", "1")
    assert set(ISSUE_KEYS) <= set(report)
    assert {key for _, key, _ in TABLE_ROWS} <= set(report)
    assert report["lost_messages"] == 0, report["lost_detail"]
    assert report["updates_completed"] > 0 and report["pose_rate_hz"] > 0
    assert set(report["processes"]) == {"worker0", "filter", "ingest", "loadtest"}
    assert all(usage["rss_mb"] > 0 for usage in report["processes"].values())
    assert "lost messages" in format_table(report)
    assert (tmp_path / "w1_p60_m16" / "filter.log").is_file()
