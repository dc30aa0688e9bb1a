"""``locnerf bag export`` and ``bag info`` on real data: the first frames of the EuRoC micro sequence
written as a bag read back as exactly the stream its folder replay (the ingest's ``source = "euroc"``
with the same odometry model) sends."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from locnerf.bags.events import bag_events
from locnerf.data.euroc import read_euroc
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.sim.events import ImageEvent, OdometryEvent
from locnerf.sim.sensors import VioConfig
from locnerf_cli.main import main
from locnerf_services.sensor_ingest.euroc_source import EurocSourceConfig, euroc_events
from tests.bags.test_bag_events import assert_same_events


def euroc_excerpt(euroc: Path, folder: Path, frames: int) -> Path:
    """A EuRoC folder of the first ``frames`` images of ``euroc`` (linked, not copied) and its whole ground truth."""
    camera = folder / "mav0" / "cam0"
    (camera / "data").mkdir(parents=True)
    lines = (euroc / "mav0/cam0/data.csv").read_text().splitlines()[: frames + 1]
    (camera / "data.csv").write_text("\n".join(lines) + "\n")
    (camera / "sensor.yaml").symlink_to(euroc / "mav0/cam0/sensor.yaml")
    for line in lines[1:]:
        name = line.split(",")[1].strip()
        (camera / "data" / name).symlink_to(euroc / "mav0/cam0/data" / name)
    (folder / "groundtruth_tum").symlink_to(euroc / "groundtruth_tum")
    return folder


def test_a_euroc_folder_exported_reads_back_as_its_replay(shared_data: Path, tmp_path, capsys):
    euroc = euroc_excerpt(shared_data / "euroc_micro_V1_01", tmp_path / "euroc", frames=8)
    assert main(["bag", "export", str(euroc), "--out", str(tmp_path / "bag"), "--downscale", "4", "--seed", "3", "--quiet"]) == 0
    written = json.loads(capsys.readouterr().out)["messages"]
    vio = VioConfig(rotation_noise=math.radians(0.057))  # the flags' defaults (the ingest's euroc source defaults to 1 mrad)
    replay = list(euroc_events(read_euroc(euroc), EurocSourceConfig(path=str(euroc), downscale=4.0, vio=vio), torch.Generator().manual_seed(3)))
    read = list(bag_events(tmp_path / "bag"))
    assert_same_events(read, replay)
    images = [event for event in read if isinstance(event, ImageEvent)]
    assert written["/camera/image_raw"] == len(images) == 8 and "/camera/depth/image_raw" not in written
    assert np.array_equal(images[0].pixels[..., 0], images[0].pixels[..., 2]), "grey frames as three equal channels"

    assert main(["bag", "info", str(tmp_path / "bag"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    topics = {row["topic"]: row for row in info["topics"]}
    assert info["storage"] == "mcap" and {topic: row["count"] for topic, row in topics.items()} == written
    odometry = [event.stamp for event in replay if isinstance(event, OdometryEvent)]
    assert topics["/odom"]["rate_hz"] == pytest.approx(15.0, rel=1e-3)
    assert topics["/odom"]["start_s"] * 1e9 == pytest.approx(nanoseconds_from_seconds(odometry[0]), abs=1e3)
    assert topics["/odom"]["end_s"] - topics["/odom"]["start_s"] == pytest.approx(odometry[-1] - odometry[0], abs=1e-6)


def test_export_refuses_an_existing_bag_before_reading_the_data(tmp_path, caplog):
    (tmp_path / "bag").mkdir()
    with caplog.at_level(logging.ERROR):
        assert main(["bag", "export", str(tmp_path / "no data here"), "--out", str(tmp_path / "bag")]) == 2
    assert f"--out {tmp_path / 'bag'}: exists already" in caplog.text
