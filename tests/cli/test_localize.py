"""``locnerf localize`` end to end on the procedural world (reduced trials)."""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path

import pytest
import torch

from locnerf.field.map_file import FORMAT_NAME, FORMAT_VERSION, HEADER, MAGIC
from locnerf_cli.main import main

REQUIRED_KEYS = {"success_rate", "median_translation_error", "median_rotation_error_deg", "mean_seconds_per_trial", "forward_passes"}


@pytest.mark.parametrize("protocol,updates", [("inerf", 100), ("global", 150)])
def test_localize_world_prints_the_summary_and_succeeds(protocol, updates, capsys):
    assert (
        main(["localize", "--map", "world", "--protocol", protocol, "--trials", "2", "--seed", "3", "--updates", str(updates), "--device", "cpu", "--json"])
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert REQUIRED_KEYS <= summary.keys()
    assert summary["trials"] == 2 and summary["protocol"] == protocol
    # Measured 20/20 successes for both protocols at these settings (README); 2 trials must pass.
    assert summary["success_rate"] == 1.0
    assert summary["forward_passes"] > 0


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--trials", "0"], "--trials 0: expected at least 1"),
        (["--preset", "fern", "--trials", "1"], "unknown preset 'fern': expected one of"),
        (["--device", "tpu", "--trials", "1"], "device 'tpu': expected auto, cpu, cuda or cuda:N"),
        (["--particles", "0", "--trials", "1", "--device", "cpu"], "--particles: must be greater than or equal to 1, got 0"),
    ],
)
def test_bad_arguments_are_refused_with_a_reason(arguments, message, caplog):
    assert main(["localize", *arguments]) == 2
    assert message in caplog.text
    assert "Traceback" not in caplog.text and "pydantic" not in caplog.text


def _map_file(path: Path, payload: bytes) -> Path:
    """``payload`` behind a well-formed version-2 header (right length and checksum)."""
    path.write_bytes(HEADER.pack(MAGIC, FORMAT_VERSION, len(payload), hashlib.sha256(payload).digest()) + payload)
    return path


def _archive(content: dict) -> bytes:
    buffer = io.BytesIO()
    torch.save(content, buffer)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (_archive({"format": FORMAT_NAME, "weights": torch.zeros(1000)})[:-600], "cannot be read as a locnerf map"),
        (_archive({"format": FORMAT_NAME, "hook": Path("elsewhere")}), "refused, the archive holds objects other than tensors"),
    ],
    ids=["truncated_archive", "pickled_object"],
)
def test_a_corrupt_map_is_refused_without_torchs_advice(tmp_path, caplog, payload, message):
    corrupt = _map_file(tmp_path / "corrupt.locmap", payload)
    assert main(["localize", "--map", str(corrupt), "--trials", "1", "--device", "cpu"]) == 2
    assert f"map file {corrupt}: {message}" in caplog.text
    assert "weights_only" not in caplog.text
