"""``locnerf demo`` runs on the embedded default and writes its plot."""

from __future__ import annotations

import json

from locnerf.cli.main import main


def test_demo_localizes_and_writes_a_plot(tmp_path, capsys):
    assert main(["demo", "--trials", "1", "--seed", "1", "--device", "cpu", "--out", str(tmp_path)]) == 0
    output = capsys.readouterr().out
    summary = json.loads(output[output.index("{") :])
    assert summary["trials"] == 1 and summary["success_rate"] == 1.0
    assert (tmp_path / "global_localization.png").stat().st_size > 10_000
