"""``locnerf bench-filter`` prints one parseable line per target with positive timings."""

from __future__ import annotations

import json

import pytest

from locnerf.cli.main import build_parser, main


def test_every_target_prints_one_json_line(capsys):
    assert main(["bench-filter", "--particles", "8", "--pixels", "4", "--repeats", "2", "--device", "cpu", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    expected = {"likelihood", "predict", "resample_multinomial", "resample_systematic", "rotation_mean", "estimate", "encode_request",
                "decode_request", "encode_result", "decode_result", "encode_image", "decode_image"}
    assert {line["target"] for line in lines} == expected
    assert all(line["median_ms"] > 0 and line["particles"] == 8 and line["pixels"] == 4 for line in lines)


def test_an_unknown_target_is_named():
    args = build_parser().parse_args(
        ["bench-filter", "--particles", "4", "--pixels", "2", "--repeats", "1", "--device", "cpu", "--targets", "predict,teleport"]
    )
    with pytest.raises(ValueError, match="teleport"):
        args.func(args)
