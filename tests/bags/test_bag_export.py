"""``locnerf bag export`` and ``bag info`` on real data: the first frames of the EuRoC micro sequence
written as a bag read back as exactly the stream its folder replay (the ingest's ``source = "euroc"``
with the same odometry model) sends; a kitchen excerpt for an SfM-built map, as the live replay for that map sends it."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

from locnerf.bags.events import bag_events
from locnerf.data.euroc import read_euroc
from locnerf.data.map_lens import MapLens
from locnerf.data.trajectory_files import write_tum
from locnerf.geometry.se3 import make_pose, pose_inverse
from locnerf.geometry.so3 import so3_exp
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.odometry.sequence import OdometrySourceConfig
from locnerf.sim.events import ImageEvent, OdometryEvent
from locnerf.sim.sensors import VioConfig
from locnerf_cli import bag as bag_cli
from locnerf_cli.main import main
from locnerf_services.sensor_ingest.euroc_source import EurocSourceConfig, euroc_events
from locnerf_services.sensor_ingest.scenario_source import ScenarioSourceConfig, scenario_events
from tests.bags.test_bag_events import assert_same_events
from tests.services.test_scenario_source import KITCHEN_SFM_LENS


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


def nerf_synthetic_folder(folder: Path, frames: int = 6) -> Path:
    """A NeRF-synthetic test split of ``frames`` 8×6 random images on a line of poses."""
    generator = np.random.default_rng(11)
    (folder / "test").mkdir(parents=True)
    entries = []
    for k in range(frames):
        cv2.imwrite(str(folder / "test" / f"r_{k}.png"), generator.integers(0, 256, (6, 8, 3), dtype=np.uint8))
        pose = np.eye(4)
        pose[:3, 3] = [0.1 * k, 0.02 * k, 4.0]
        entries.append({"file_path": f"./test/r_{k}", "transform_matrix": pose.tolist()})
    (folder / "transforms_test.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": entries}))
    return folder


def test_a_sequence_exported_with_a_trajectory_file_as_its_odometry(tmp_path, capsys):
    folder = nerf_synthetic_folder(tmp_path / "scene")
    stamps = np.arange(0.0, 2.0, 0.05)
    poses = torch.stack(
        [make_pose(so3_exp(torch.tensor([0.0, 0.1 * t, 0.0], dtype=torch.float64)), torch.tensor([t, 0.0, -0.5 * t], dtype=torch.float64)) for t in stamps]
    )
    write_tum(tmp_path / "vio.txt", stamps, poses)
    flags = ["--frame-rate", "5", "--odom-rate", "5", "--image-rate", "5", "--odometry", str(tmp_path / "vio.txt")]
    assert main(["bag", "export", str(folder), "--out", str(tmp_path / "bag"), *flags, "--quiet"]) == 0
    capsys.readouterr()
    odometry = OdometrySourceConfig(source=str(tmp_path / "vio.txt"))
    replay = ScenarioSourceConfig(
        sequence=str(folder), frame_rate=5.0, image_rate=5.0, vio=VioConfig(rate=5.0, rotation_noise=math.radians(0.057)), odometry=odometry
    )
    events = list(scenario_events(replay, 0))
    read = list(bag_events(tmp_path / "bag"))
    assert_same_events(read, events)
    for event in (event for event in read if isinstance(event, OdometryEvent)):
        (index,) = np.flatnonzero(np.isclose(stamps, event.stamp))
        assert torch.allclose(event.T_odom_body, poses[index], atol=1e-9), "the file's pose at the stamp"


def test_euroc_export_refuses_another_odometry(shared_data: Path, tmp_path, caplog):
    with caplog.at_level(logging.ERROR):
        assert main(["bag", "export", str(shared_data / "euroc_micro_V1_01"), "--out", str(tmp_path / "bag"), "--odometry", "rgbd"]) == 2
    assert "a EuRoC folder is exported with its simulated odometry" in caplog.text and not (tmp_path / "bag").exists()


def sfm_built_map(lens: MapLens, T_depth_colour: torch.Tensor) -> SimpleNamespace:
    """What ``open_map`` gives for a kitchen map built by ``map build --sfm``: its metadata (the pose source, the
    depth camera's placement, the lens SfM estimated) and its pinhole camera."""
    record = {"intrinsics": lens.lens.model_dump(), "distortion": list(lens.distortion)}
    metadata = {"poses": "sfm", "T_depth_colour": T_depth_colour.tolist(), "sfm": {"camera": record}}
    return SimpleNamespace(metadata=metadata, default_intrinsics=lens.camera)


def test_a_kitchen_bag_for_an_sfm_built_map_is_the_stream_its_live_replay_sends(shared_data: Path, tmp_path, capsys, caplog, monkeypatch):
    """``--map`` of an SfM-built map: the bag's colour images are resampled through the map's lens onto its camera, its
    CameraInfo is that camera, its ground truth the SfM poses the map lives among, and its depth camera placed by the
    map: the very events the live replay for that map (``eval tracking --live --poses sfm``) sends. A map built from
    the other ground truth is refused, naming both."""
    kitchen = shared_data / "7scenes_redkitchen"
    lens = KITCHEN_SFM_LENS
    offset = make_pose(so3_exp(torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64)), torch.tensor([0.03, 0.0, 0.0], dtype=torch.float64))
    monkeypatch.setattr(bag_cli, "open_map", lambda path, device: sfm_built_map(lens, offset))
    flags = ["--split", "test", "--downscale", "8", "--frame-rate", "30", "--duration", "0.4", "--image-rate", "5", "--map", "kitchen_sfm.locmap"]
    assert main(["bag", "export", str(kitchen), "--out", str(tmp_path / "bag"), *flags, "--poses", "sfm", "--quiet"]) == 0
    capsys.readouterr()
    replay = ScenarioSourceConfig(
        sequence=str(kitchen.resolve()), split="test", downscale=8, frame_rate=30.0, duration=0.4, image_rate=5.0,
        vio=VioConfig(rotation_noise=math.radians(0.057)), T_depth_colour=offset.tolist(), lens=lens, poses="sfm",
    )  # fmt: skip
    events = list(scenario_events(replay, 0))
    read = list(bag_events(tmp_path / "bag"))
    assert_same_events(read, events)
    images = [event for event in read if isinstance(event, ImageEvent)]
    assert images and images[0].intrinsics == lens.camera.scaled(80 / 160) and images[0].depth is not None
    torch.testing.assert_close(images[0].depth.T_cam_depth, pose_inverse(offset))
    plain = [event for event in scenario_events(replay.model_copy(update={"lens": None}), 0) if isinstance(event, ImageEvent)]
    assert not np.array_equal(images[0].pixels, plain[0].pixels), "resampled through the lens"

    with caplog.at_level(logging.ERROR):
        assert main(["bag", "export", str(kitchen), "--out", str(tmp_path / "other"), *flags, "--quiet"]) == 2
    assert "--poses dslam: the map was built from sfm poses" in caplog.text and not (tmp_path / "other").exists()
