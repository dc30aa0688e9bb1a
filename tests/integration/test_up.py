"""``locnerf up --duration S --json``: all services locally, one command, a summary at the end.

Tolerances: 10 s after the first pose from a lost start the filter has converged (it does in about 6 s of
sensor time in the procedural world), so the final error is below 0.25 m and 5°; the pose rate
is the odometry rate (15 Hz) within 20 %.
"""

from __future__ import annotations

import json
import subprocess
import sys

from tests.integration.conftest import REPO


def test_up_runs_everything_and_prints_a_summary(tmp_path):
    plot = tmp_path / "run.png"
    command = [sys.executable, "-m", "cli.main", "up", "--duration", "10", "--json", "--port", "0", "--logs", str(tmp_path), "--plot", str(plot)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert result.returncode == 0, result.stderr + "".join(p.read_text()[-2000:] for p in tmp_path.glob("*.log"))
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    for key in ("pose_rate_hz", "update_hz", "updates_merged", "stale_results", "bad_messages", "final_translation_error", "final_rotation_error_deg"):
        assert key in summary, key
    assert 12.0 <= summary["pose_rate_hz"] <= 18.0
    assert summary["updates_merged"] > 10 and summary["bad_messages"] == 0
    assert summary["final_translation_error"] < 0.25 and summary["final_rotation_error_deg"] < 5.0
    assert plot.is_file() and plot.stat().st_size > 10_000
