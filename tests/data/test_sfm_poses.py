"""7-Scenes' SfM pseudo ground truth (``--poses sfm``): parsing against a float64 oracle, the reader's use of it,
the refusals of bad input, and the real redkitchen files against the data set's own (dSLAM) poses."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from pydantic import ValidationError

from locnerf.data import read_dataset, read_seven_scenes
from locnerf.data.colour_camera import check_map_poses, read_on_map_camera
from locnerf.data.sfm_poses import read_sfm_poses, sfm_pose_files
from locnerf.errors import DatasetError
from locnerf.field.map_file import read_map_archive
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.geometry.quaternion import matrix_to_quaternion
from locnerf.sim.events import GroundTruthEvent
from locnerf_cli.main import main
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from tests.data.test_seven_scenes import CAMERA, _fake_scene

FOCAL = 525.505
SPREAD = 0.05
"""Pose spread of the full-size fake scene (a small room keeps its map's surface-distance layer small)."""


def _world_to_camera(index: int, spread: float = 1.0) -> np.ndarray:
    """A seeded world-to-camera pose (4, 4) float64: rotation by Rodrigues' formula (OpenCV), translation drawn
    (up to 1.5 rad and 2 units times ``spread``)."""
    rng = np.random.default_rng(index)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(spread * rng.uniform(-1.5, 1.5, 3))[0]
    pose[:3, 3] = spread * rng.uniform(-2.0, 2.0, 3)
    return pose


def _line(name: str, index: int, focal: float = FOCAL, spread: float = 1.0) -> str:
    pose = _world_to_camera(index, spread)
    q = matrix_to_quaternion(torch.from_numpy(pose[:3, :3])).tolist()  # (w, x, y, z), an independent conversion
    return f"{name} {' '.join(f'{v:.15f}' for v in q)} {' '.join(f'{v:.15f}' for v in pose[:3, 3])} {focal}"


def _write_pgt(root: Path, lines: list[str]) -> Path:
    folder = root / "pgt_sfm"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "scene_seq-01_sfm_pgt.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_parses_world_to_camera_lines_into_camera_to_world_poses(tmp_path: Path) -> None:
    path = _write_pgt(tmp_path, [_line("seq-01/frame-000000.color.png", 0), _line("seq-03/frame-000017.color.png", 1, 500.0)])
    poses = read_sfm_poses([path])
    assert sorted(poses) == ["seq-01/frame-000000", "seq-03/frame-000017"]
    for key, index, focal in (("seq-01/frame-000000", 0, FOCAL), ("seq-03/frame-000017", 1, 500.0)):
        np.testing.assert_allclose(poses[key].T_world_cam, np.linalg.inv(_world_to_camera(index)), atol=1e-12)
        assert poses[key].focal == focal and poses[key].source.endswith(":1" if index == 0 else ":2")


def test_reader_takes_colour_poses_focal_and_depth_offset(tmp_path: Path) -> None:
    """A fake scene whose frames 3-5 sit in seq-02 while the file names them seq-01 (the frame number finds them)."""
    root = _fake_scene(tmp_path / "scene")
    _write_pgt(root, [_line(f"seq-01/frame-{i:06d}.color.png", i, 7.0) for i in range(6)])
    offset = torch.eye(4, dtype=torch.float64)
    offset[:3, 3] = torch.tensor([0.03, 0.01, -0.02], dtype=torch.float64)
    test = read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA, poses="sfm", T_depth_colour=offset)
    expected = opencv_to_opengl(torch.from_numpy(np.stack([np.linalg.inv(_world_to_camera(i)) for i in range(3, 6)])))
    torch.testing.assert_close(test.T_world_cam, expected, atol=1e-12, rtol=0)
    # The files' focal (at 640 px wide) scaled to this 8-px camera, halved by the downscale; the centre stays the given one's.
    assert test.intrinsics.fx == pytest.approx(7.0 * 8 / 640 / 2) and (test.intrinsics.cx, test.intrinsics.cy) == (1.75, 1.25)
    torch.testing.assert_close(test.T_cam_depth, torch.linalg.inv(offset))
    # The data set's own poses are untouched by default.
    dslam = read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)
    assert dslam.T_cam_depth is None and not torch.allclose(dslam.T_world_cam, test.T_world_cam)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("seq-01/frame-000000.color.png 1 0 0 0 0 0 0", r"scene_seq-01_sfm_pgt\.txt:1: .*expected 'seq-NN/frame-NNNNNN\.color\.png qw qx qy qz tx ty tz f'"),
        ("seq-01/frame-000000.color.png 0.9 0 0 0 0 0 0 525", r":1: quaternion of norm 0\.900000, expected a unit quaternion"),
        ("seq-01/frame-000000.color.png 1 0 0 0 0 0 zero 525", r":1: .*expected 8 numbers"),
        ("seq-01/frame-000000.color.png 1 0 0 0 0 0 0 -5", r":1: focal length -5\.0, expected > 0"),
        ("frame.png 1 0 0 0 0 0 0 525", r":1: 'frame\.png 1 0 0 0 0 0 0 525', expected"),
    ],
)
def test_refuses_bad_lines_naming_file_and_line(tmp_path: Path, line: str, expected: str) -> None:
    path = _write_pgt(tmp_path, [line])
    with pytest.raises(DatasetError, match=expected):
        read_sfm_poses([path])


def test_refuses_a_frame_given_twice(tmp_path: Path) -> None:
    path = _write_pgt(tmp_path, [_line("seq-01/frame-000000.color.png", 0), _line("seq-01/frame-000000.color.png", 1)])
    with pytest.raises(DatasetError, match=r":2: frame seq-01/frame-000000\.color\.png already given at .*:1"):
        read_sfm_poses([path])


def test_refuses_missing_files_frames_and_unknown_pose_names(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    with pytest.raises(FileNotFoundError, match=r"scene/pgt_sfm/\*_sfm_pgt\.txt: no such file"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA, poses="sfm")
    _write_pgt(root, [_line("seq-01/frame-000000.color.png", 0), _line("seq-01/frame-000001.color.png", 1)])
    with pytest.raises(DatasetError, match=r"seq-01/frame-000002: no line in .*sfm_pgt\.txt"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA, poses="sfm")
    with pytest.raises(DatasetError, match=r"--poses 'colmap': expected one of dslam, sfm"):
        read_dataset(root, "train", downscale=2, poses="colmap")


def test_a_map_is_scored_only_against_the_poses_it_was_built_from(tmp_path: Path) -> None:
    class Built:
        metadata = {"poses": "sfm"}

    root = _fake_scene(tmp_path / "scene")
    assert check_map_poses(Built(), "sfm") == "sfm"
    with pytest.raises(DatasetError, match=r"--poses dslam: the map was built from sfm poses .* --poses sfm"):
        read_on_map_camera(root, Built(), "dslam", split="test", downscale=2)
    with pytest.raises(DatasetError, match=r"--poses 'x': expected one of dslam, sfm"):
        check_map_poses(Built(), "x")


def test_real_redkitchen_sfm_poses_agree_with_dslam_after_a_similarity(shared_data: Path) -> None:
    """Every 20th frame: after a similarity fit (Umeyama) of the SfM colour-camera centres onto the dSLAM
    depth-camera centres, they agree to a few centimetres (over all 1000 frames: median 3.7 cm, largest 10.8 cm, scale 0.993;
    the colour camera sits ~3 cm from the depth camera, inside that)."""
    folder = shared_data / "7scenes_redkitchen"
    sfm = read_seven_scenes(folder, split="all", downscale=8, stride=20, depth=False, poses="sfm")
    dslam = read_seven_scenes(folder, split="all", downscale=8, stride=20, depth=False)
    assert sfm.names == dslam.names and len(sfm) == 50
    assert sfm.intrinsics.fx == pytest.approx(525.505 / 8)
    assert len(sfm_pose_files(folder)) == 1
    source, target = sfm.T_world_cam[:, :3, 3].numpy(), dslam.T_world_cam[:, :3, 3].numpy()
    transform, scale = cv2.estimateAffine3D(source, target, force_rotation=True)
    residual = np.linalg.norm(scale * source @ transform[:, :3].T + transform[:, 3] - target, axis=1)
    assert scale == pytest.approx(0.993, abs=0.01)
    assert np.median(residual) < 0.05 and residual.max() < 0.12
    # The map's up axis (the gravity file's, rotated into the SfM world) seen from each camera is the dSLAM one's.
    in_sfm = sfm.T_world_cam[:, :3, :3].transpose(1, 2) @ torch.tensor(sfm.normalization.up, dtype=torch.float64)
    in_dslam = dslam.T_world_cam[:, :3, :3].transpose(1, 2) @ torch.tensor(dslam.normalization.up, dtype=torch.float64)
    angles = torch.rad2deg(torch.acos((in_sfm * in_dslam).sum(-1).clamp(-1, 1)))
    assert float(angles.median()) < 3.0


def _full_size_scene(root: Path) -> Path:
    """seq-01 frames 0-2 (train) and seq-02 frames 3-5 (test) at 7-Scenes' sizes: colour 640x480, depth 320x240."""
    for sequence, numbers in ((1, range(0, 3)), (2, range(3, 6))):
        folder = root / f"seq-{sequence:02d}"
        folder.mkdir(parents=True)
        for number in numbers:
            stem = folder / f"frame-{number:06d}"
            cv2.imwrite(f"{stem}.color.png", np.full((480, 640, 3), 40 * number, np.uint8))
            cv2.imwrite(f"{stem}.depth.png", np.full((240, 320), 1500, np.uint16))
            np.savetxt(f"{stem}.pose.txt", np.eye(4))
    (root / "TrainSplit.txt").write_text("sequence1\n")
    (root / "TestSplit.txt").write_text("sequence2\n")
    _write_pgt(root, [_line(f"seq-01/frame-{i:06d}.color.png", i, spread=SPREAD) for i in range(6)])
    return root


def test_the_replay_source_streams_the_sfm_ground_truth(tmp_path: Path) -> None:
    """The ingest's replay of a 7-Scenes folder with ``replay.poses = "sfm"``: its ground-truth events are the
    SfM colour-camera poses (OpenGL axes), the depth camera placed by the calibration given; unknown names refused."""
    root = _full_size_scene(tmp_path / "scene")
    offset = torch.eye(4, dtype=torch.float64)
    offset[:3, 3] = torch.tensor([0.03, 0.0, 0.0], dtype=torch.float64)
    replay = {"path": str(root), "split": "test", "downscale": 8, "frame_rate": 1.0, "poses": "sfm", "T_depth_colour": offset.tolist()}
    replay["vio"] = {"rate": 1.0}
    events = list(sensor_events(IngestConfig(source="replay", replay=replay)))
    truths = [event.T_world_cam for event in events if isinstance(event, GroundTruthEvent)]
    expected = opencv_to_opengl(torch.from_numpy(np.stack([np.linalg.inv(_world_to_camera(i, SPREAD)) for i in range(3, 6)])))
    torch.testing.assert_close(torch.stack(truths), expected, atol=1e-9, rtol=0)
    with pytest.raises(ValidationError, match=r"poses\n  Input should be 'dslam' or 'sfm'"):
        IngestConfig(source="replay", replay={**replay, "poses": "colmap"})


def test_map_build_and_eval_with_sfm_poses(tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    """``map build --poses sfm`` records its pose source and scores the test split against the SfM poses;
    ``map eval`` of that map with the default dSLAM poses is refused, with ``--poses sfm`` it scores, and so does
    ``map ceiling``."""
    root = _full_size_scene(tmp_path / "scene")
    out = tmp_path / "sfm.locmap"
    build = ["map", "build", str(root), "--out", str(out), "--poses", "sfm", "--downscale", "32", "--steps", "3", "--voxels", "512", "--device", "cpu"]
    assert main(build) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["poses"] == "sfm" and report["heldout_views"] == 3
    metadata = read_map_archive(out)["info"]["metadata"]
    assert metadata["poses"] == "sfm"
    with caplog.at_level(logging.ERROR):
        assert main(["map", "eval", str(out), str(root), "--downscale", "32", "--device", "cpu", "--json"]) != 0
    assert "--poses dslam: the map was built from sfm poses" in caplog.text
    assert main(["map", "eval", str(out), str(root), "--downscale", "32", "--device", "cpu", "--json", "--poses", "sfm"]) == 0
    assert json.loads(capsys.readouterr().out)["views"] == 3
    ceiling = ["map", "ceiling", str(out), "--data", str(root), "--stride", "1", "--downscale", "32", "--candidates", "1", "--device", "cpu", "--json"]
    assert main([*ceiling, "--poses", "sfm"]) == 0  # the test views posed by the SfM poses, as the map
    assert json.loads(capsys.readouterr().out)["summary"]["views"] == 3
