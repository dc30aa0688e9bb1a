"""The sweep's CSV holds one row per case with the fixed columns; the plot is written."""

from __future__ import annotations

import csv

from locnerf.eval.loadtest_sweep import SWEEP_COLUMNS, plot_sweep, write_sweep_csv


def test_csv_and_png_of_a_sweep(tmp_path):
    rows = [
        {
            "workers": w,
            "particles": p,
            "pixels": 32,
            "rays": 32 * p,
            "update_hz": 10.0 / p * w,
            "update_latency_p50_ms": p / w,
            "update_latency_p99_ms": 2 * p / w,
            "worker_compute_p50_ms": None,
            "pose_rate_hz": 15.0,
            "pose_jitter_p99_ms": 1.0,
            "end_to_end_latency_p99_ms": 2.0,
            "dropped_frames": 3,
            "lost_messages": 0,
            "processes": {},
        }
        for w in (1, 2)
        for p in (100, 300)
    ]
    with write_sweep_csv(rows, tmp_path / "sweep.csv").open() as handle:
        table = list(csv.DictReader(handle))
    assert tuple(table[0]) == SWEEP_COLUMNS
    assert [(r["workers"], r["particles"]) for r in table] == [("1", "100"), ("1", "300"), ("2", "100"), ("2", "300")]
    png = plot_sweep(rows, tmp_path / "sweep.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
