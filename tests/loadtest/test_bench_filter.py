"""``locnerf bench filter|world`` print one parseable row per measurement (table or JSON lines)."""

from __future__ import annotations

import json

import pytest

from locnerf_cli.bench_table import BenchTable
from locnerf_cli.main import build_parser, main


def test_every_filter_target_prints_one_json_line(capsys):
    assert main(["bench", "filter", "--particles", "8", "--pixels", "4", "--repeats", "2", "--device", "cpu", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    expected = {
        "likelihood",
        "likelihood_converged",
        "likelihood_warp",
        "depth_rendered",
        "depth_warp",
        "predict",
        "resample_multinomial",
        "resample_systematic",
        "rotation_mean",
        "estimate",
        "encode_request",
        "decode_request",
        "encode_result",
        "decode_result",
        "encode_image",
        "decode_image",
    }
    assert {line["target"] for line in lines} == expected
    assert all(line["median_ms"] > 0 and line["particles"] == 8 and line["pixels"] == 4 for line in lines)


def test_the_filter_table_has_a_settings_line_a_header_and_one_row_per_target(capsys):
    assert main(["bench", "filter", "--particles", "4", "--pixels", "2", "--repeats", "1", "--device", "cpu", "--targets", "predict,estimate"]) == 0
    settings, header, *rows = capsys.readouterr().out.strip().splitlines()
    assert json.loads(settings.removeprefix("# "))["particles"] == 4
    assert header.split() == ["target", "median_ms", "p90_ms", "calls_per_s"]
    assert [row.split()[0] for row in rows] == ["predict", "estimate"]
    assert all(float(row.split()[1]) > 0 for row in rows)


def test_an_unknown_target_is_named():
    args = build_parser().parse_args(
        ["bench", "filter", "--particles", "4", "--pixels", "2", "--repeats", "1", "--device", "cpu", "--targets", "predict,teleport"]
    )
    with pytest.raises(ValueError, match="teleport"):
        args.func(args)


def test_bench_world_prints_one_row_per_dtype(capsys):
    assert main(["bench", "world", "--rays", "64", "--repeats", "1", "--device", "cpu", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    assert [line["dtype"] for line in lines] == ["float32", "float64"]
    assert all(line["rays"] == 64 and line["median_ms"] > 0 and line["threads"] == 1 for line in lines)


def test_the_old_top_level_commands_are_gone():
    for old in ("bench-filter", "bench-world"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([old])


def test_a_row_without_a_column_is_refused(capsys):
    table = BenchTable(("target", "median_ms"), {"device": "cpu"}, as_json=False)
    with pytest.raises(ValueError, match="median_ms"):
        table.row({"target": "predict"})
    table.row({"target": "predict", "median_ms": 0.5})
    assert capsys.readouterr().out.strip().splitlines()[-1].split() == ["predict", "0.5"]
