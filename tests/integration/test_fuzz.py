"""``locnerf fuzz``, short: 200 hostile payloads per subscribed key at real processes on loopback Zenoh.

Checked: every process alive, every payload counted under its kind or dropped by design (the
services' own counters say which), no payload accepted, resident memory growth within the default
50 MB, and a pose for every odometry stamp during the fuzzing. The pose *rate* is reported, not
asserted (no timed assertions in tests); docs/RELIABILITY.md has the measured full run.
"""

from __future__ import annotations

import json
import subprocess
import sys

from locnerf.eval.fuzz_payloads import TARGETS
from tests.integration.conftest import REPO


def test_fuzz_every_subscribed_key(tmp_path):
    command = [sys.executable, "-m", "locnerf_cli.main", "fuzz", "--payloads", "200", "--seed", "1", "--out", str(tmp_path), "--json"]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=400, cwd=REPO)
    report = json.loads(finished.stdout.strip().splitlines()[-1])
    assert [(t["service"], t["key"]) for t in report["targets"]] == [(t.service, t.topic.suffix) for t in TARGETS]
    for target in report["targets"]:
        assert target["sent"] == 200 and target["accepted"] == 0, target
        assert target["agree"], target
        assert target["counted"] > 0
    checks = report["checks"]
    assert checks["alive"] and checks["counts_agree"] and checks["memory_bounded"], report["memory_mb"]
    assert report["pose_stream"]["odometry_stamps_without_pose"] == 0 and report["pose_stream"]["poses"] > 0
