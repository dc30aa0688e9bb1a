"""The EuRoC reader and ingest source against the shipped V1_01 excerpt and broken copies of it."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.euroc import read_euroc
from locnerf.geometry.frames import opengl_to_opencv
from locnerf.geometry.quaternion import quaternion_to_matrix
from locnerf.geometry.se3 import pose_inverse
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf.sim.sensors import VioConfig
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from locnerf_services.sensor_ingest.euroc_source import EurocSourceConfig, euroc_events, euroc_T_body_cam

QUIET = VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, rotation_noise=0.0, translation_noise=0.0)


@pytest.fixture
def euroc(shared_data: Path) -> Path:
    return shared_data / "euroc_micro_V1_01"


def test_reader_keeps_stamps_and_calibration(euroc: Path) -> None:
    sequence = read_euroc(euroc)
    listing = [line.split(",") for line in (euroc / "mav0/cam0/data.csv").read_text().splitlines()[1:]]
    assert len(sequence.image_paths) == len(listing) == 95
    assert sequence.image_stamps[0] == pytest.approx(int(listing[0][0]) / 1e9, abs=1e-6)
    assert sequence.camera.intrinsics.fx == pytest.approx(458.654) and sequence.camera.intrinsics.width == 752
    assert sequence.camera.T_body_cam[0, 1] == pytest.approx(-0.999880929698)
    # The first TUM row: position and quaternion (qx qy qz qw) of the body.
    row = np.loadtxt(euroc / "groundtruth_tum/V101_gt.txt")[0]
    torch.testing.assert_close(sequence.T_world_body[0, :3, 3], torch.from_numpy(row[1:4]))
    torch.testing.assert_close(sequence.T_world_body[0, :3, :3], quaternion_to_matrix(torch.from_numpy(row[[7, 4, 5, 6]])))


def test_frames_are_undistorted_rgb(euroc: Path) -> None:
    sequence = read_euroc(euroc)
    frame = sequence.read_image(0)
    assert frame.shape == (480, 752, 3) and frame.dtype == np.uint8
    assert (frame[..., 0] == frame[..., 2]).all()
    raw = cv2.imread(str(sequence.image_paths[0]), cv2.IMREAD_GRAYSCALE)
    k = sequence.camera.intrinsics
    matrix = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1.0]])
    expected = cv2.undistort(raw.astype(np.float32) / 255.0, matrix, sequence.camera.distortion)
    assert np.abs(frame[..., 0].astype(np.float32) / 255.0 - expected).max() <= 1.0 / 255.0 + 1e-6
    assert sequence.read_image(0, downscale=2).shape == (240, 376, 3)


def test_events_are_ordered_and_odometry_follows_the_camera(euroc: Path, generator: torch.Generator) -> None:
    sequence = read_euroc(euroc)
    events = list(euroc_events(sequence, EurocSourceConfig(vio=QUIET), generator))
    stamps = [e.stamp for e in events]
    assert stamps == sorted(stamps)
    images = [e for e in events if isinstance(e, ImageEvent)]
    truth = [e for e in events if isinstance(e, GroundTruthEvent)]
    odometry = [e for e in events if isinstance(e, OdometryEvent)]
    assert len(images) == 95 and images[0].stamp == pytest.approx(sequence.image_stamps[0])
    span = sequence.image_stamps[-1] - sequence.image_stamps[0]
    assert len(odometry) == len(truth) == int(span * 15.0) + 1
    # The first truth is the first ground-truth body pose times T_BS, in OpenGL camera axes.
    first = sequence.T_world_body[0] @ sequence.camera.T_body_cam
    torch.testing.assert_close(opengl_to_opencv(truth[0].T_world_cam), first, atol=1e-5, rtol=0)
    # Noise-free odometry reproduces the true relative motion.
    torch.testing.assert_close(
        pose_inverse(odometry[0].T_odom_body) @ odometry[-1].T_odom_body, pose_inverse(truth[0].T_world_cam) @ truth[-1].T_world_cam, atol=1e-9, rtol=0
    )


def test_ingest_config_selects_euroc_and_refuses_broken_folders(euroc: Path, tmp_path: Path) -> None:
    events = sensor_events(IngestConfig(source="euroc", euroc=EurocSourceConfig(path=str(euroc))))
    assert isinstance(next(iter(events)), GroundTruthEvent)
    with pytest.raises(ValueError, match="euroc.path"):
        sensor_events(IngestConfig(source="euroc"))
    with pytest.raises(FileNotFoundError, match="data.csv"):
        read_euroc(tmp_path)
    broken = tmp_path / "broken"
    shutil.copytree(euroc / "mav0" / "cam0", broken / "mav0" / "cam0")
    with pytest.raises(FileNotFoundError, match="ground truth"):
        read_euroc(broken)
    first_image = sorted((broken / "mav0/cam0/data").iterdir())[0]
    first_image.unlink()
    with pytest.raises(FileNotFoundError, match=first_image.name):
        read_euroc(broken, groundtruth=euroc / "groundtruth_tum/V101_gt.txt")


def test_ground_truth_outside_the_images_is_refused(euroc: Path, tmp_path: Path) -> None:
    rows = np.loadtxt(euroc / "groundtruth_tum/V101_gt.txt")
    rows[:, 0] += 1e4
    shifted = tmp_path / "late.txt"
    np.savetxt(shifted, rows)
    with pytest.raises(ValueError, match="does not overlap"):
        read_euroc(euroc, groundtruth=shifted)
    assert len(list(itertools.islice(euroc_events(read_euroc(euroc), EurocSourceConfig(), torch.Generator()), 3))) == 3


def test_body_odometry_moves_the_camera_through_t_bs(euroc: Path, generator: torch.Generator) -> None:
    """With odometry of the body, T_body_cam (T_BS in OpenGL axes) carries it to the camera's motion."""
    sequence = read_euroc(euroc)
    events = list(euroc_events(sequence, EurocSourceConfig(vio=QUIET, odometry_frame="body"), generator))
    truth = [e.T_world_cam for e in events if isinstance(e, GroundTruthEvent)]
    odometry = [e.T_odom_body for e in events if isinstance(e, OdometryEvent)]
    T_body_cam = euroc_T_body_cam(sequence.camera)
    torch.testing.assert_close(opengl_to_opencv(T_body_cam), sequence.camera.T_body_cam)
    camera_motion = pose_inverse(odometry[0] @ T_body_cam) @ odometry[-1] @ T_body_cam
    torch.testing.assert_close(camera_motion, pose_inverse(truth[0]) @ truth[-1], atol=1e-9, rtol=0)
    body_motion = pose_inverse(odometry[0]) @ odometry[-1]
    assert not torch.allclose(body_motion, camera_motion, atol=1e-3), "the body and the camera move differently"
