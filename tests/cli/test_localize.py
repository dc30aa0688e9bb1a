"""``locnerf localize`` end to end on the procedural world (reduced trials)."""

from __future__ import annotations

import json

import pytest

from cli.main import main

REQUIRED_KEYS = {"success_rate", "median_translation_error", "median_rotation_error_deg", "mean_seconds_per_trial", "forward_passes"}


@pytest.mark.parametrize("protocol,updates", [("inerf", 100), ("global", 150)])
def test_localize_world_prints_the_summary_and_succeeds(protocol, updates, capsys):
    assert main(["localize", "--map", "world", "--protocol", protocol, "--trials", "2", "--seed", "3", "--updates", str(updates), "--device", "cpu", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert REQUIRED_KEYS <= summary.keys()
    assert summary["trials"] == 2 and summary["protocol"] == protocol
    # Measured 20/20 successes for both protocols at these settings (README); 2 trials must pass.
    assert summary["success_rate"] == 1.0
    assert summary["forward_passes"] > 0


def test_bad_arguments_are_refused_with_a_reason(capsys):
    assert main(["localize", "--trials", "0"]) == 2
    assert main(["localize", "--preset", "fern", "--trials", "1"]) == 2
    assert main(["localize", "--device", "tpu", "--trials", "1"]) == 2
