"""``locnerf up --until-updates N --json``: all services locally, one command, a summary at the end.

Counted, not timed: the run stops once the filter has merged 40 updates, however long that takes
on the machine. Tolerances: from a lost start the filter has converged by then (about 30 updates
in the procedural world), so the final error is below 0.25 m and 5°; every odometry message
between the first and the last pose got its pose.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib

from tests.integration.conftest import REPO

UPDATES = 40


def test_up_runs_everything_and_prints_a_summary(tmp_path):
    plot = tmp_path / "run.png"
    command = [
        sys.executable,
        "-m",
        "locnerf_cli.main",
        "up",
        "--until-updates",
        str(UPDATES),
        "--json",
        "--port",
        "0",
        "--seed",
        "3",
        "--logs",
        str(tmp_path),
        "--plot",
        str(plot),
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert result.returncode == 0, result.stderr + "".join(p.read_text()[-2000:] for p in tmp_path.glob("*.log"))
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    for key in ("pose_rate_hz", "update_hz", "updates_merged", "stale_results", "bad_messages", "final_translation_error", "final_rotation_error_deg"):
        assert key in summary, key
    assert summary["updates_merged"] >= UPDATES and summary["bad_messages"] == 0
    assert summary["poses"] > 0 and summary["odometry_without_pose"] == 0
    assert summary["final_translation_error"] < 0.25 and summary["final_rotation_error_deg"] < 5.0
    assert plot.is_file() and plot.stat().st_size > 10_000
    configs = {name: tomllib.loads((tmp_path / f"{name}.toml").read_text()) for name in ("ingest", "filter", "worker0")}
    assert configs["ingest"]["wait_for_workers"] == 1 and configs["ingest"]["seed"] == 3
    assert configs["filter"]["seed"] == 3 and configs["worker0"]["worker_id"] == "worker0"
