"""Run ``locnerf loadtest ... --device cpu --out DIR --json`` as a process and read its JSON report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any


def run_loadtest(out: Path, *flags: str) -> dict[str, Any]:
    """The report of ``locnerf loadtest <flags> --device cpu --out <out> --json`` (asserts exit code 0)."""
    command = [sys.executable, "-m", "locnerf_cli.main", "loadtest", *flags, "--device", "cpu", "--out", str(out), "--json"]
    finished = subprocess.run(command, capture_output=True, text=True, timeout=240)
    assert finished.returncode == 0, finished.stderr[-3000:]
    return json.loads(finished.stdout.strip().splitlines()[-1])
