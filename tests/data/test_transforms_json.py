"""NeRF-synthetic and nerfstudio transforms.json readers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from locnerf.data import dataset_format, read_dataset, read_nerf_synthetic, read_nerfstudio


def test_nerf_synthetic_split_composited_and_downscaled(shared_data: Path) -> None:
    lego = shared_data / "nerf_synthetic" / "lego"
    views = read_nerf_synthetic(lego, split="val", background="white", downscale=8, skip_missing=True)
    assert dataset_format(lego) == "nerf_synthetic"
    assert views.images.shape == (7, 100, 100, 3)
    content = json.loads((lego / "transforms_val.json").read_text())
    assert views.intrinsics.fx == pytest.approx(50.0 / math.tan(0.5 * content["camera_angle_x"]))
    assert (views.intrinsics.cx, views.intrinsics.cy) == (49.5, 49.5)  # Blender's centred camera, 100x100
    torch.testing.assert_close(views.T_world_cam[0], torch.tensor(content["frames"][0]["transform_matrix"], dtype=torch.float64))
    # Corners are transparent background: white after compositing, black on black.
    assert float(views.images[:, 0, 0].min()) == pytest.approx(1.0)
    black = read_nerf_synthetic(lego, split="val", background="black", downscale=8, skip_missing=True)
    assert float(black.images[:, 0, 0].max()) == pytest.approx(0.0)
    # Blender scenes are z-up; cameras sit on the upper hemisphere.
    assert views.normalization.up == (0.0, 0.0, 1.0)
    assert bool((views.T_world_cam[:, 2, 3] > 0).all())


def test_a_folder_with_only_a_test_split_is_nerf_synthetic(shared_data: Path) -> None:
    orbit = shared_data / "nerf_synthetic" / "lego_test_orbit"
    assert dataset_format(orbit) == "nerf_synthetic"
    assert len(read_dataset(orbit, split="test", downscale=8)) == 200


def test_nerf_synthetic_missing_images_refused_or_skipped(shared_data: Path) -> None:
    lego = shared_data / "nerf_synthetic" / "lego"
    with pytest.raises(FileNotFoundError, match="r_1"):
        read_nerf_synthetic(lego, split="test", downscale=8)
    present = read_dataset(lego, split="test", downscale=8, skip_missing=True)
    assert len(present) == 25


def _write_nerfstudio(folder: Path, shared: dict, frames: list[dict], images: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for frame, image in zip(frames, images):
        cv2.imwrite(str(folder / frame["file_path"]), image)
    path = folder / "transforms.json"
    path.write_text(json.dumps({"aabb": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], **shared, "frames": frames}))
    return path


def _frames(count: int) -> list[dict]:
    frames = []
    for index in range(count):
        pose = np.eye(4)
        pose[0, 3] = 0.1 * index
        frames.append({"file_path": f"frame_{index:03d}.png", "transform_matrix": pose.tolist()})
    return frames


def test_nerfstudio_undistorts_and_downscales(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (40, 60, 3), dtype=np.uint8) for _ in range(3)]
    camera = {"fl_x": 50.0, "fl_y": 52.0, "cx": 29.0, "cy": 21.0, "w": 60, "h": 40, "k1": 0.1, "k2": -0.02, "p1": 0.001, "p2": 0.002}
    path = _write_nerfstudio(tmp_path / "ns", camera, _frames(3), images)
    views = read_nerfstudio(path)
    # The file's principal point is in the corner convention: OpenCV's (pixel centres at integers) is 0.5 less.
    assert (views.intrinsics.cx, views.intrinsics.cy) == (28.5, 20.5)
    matrix = np.array([[50.0, 0, 28.5], [0, 52.0, 20.5], [0, 0, 1]])
    expected = cv2.undistort(images[1][:, :, ::-1].astype(np.float32) / 255.0, matrix, np.array([0.1, -0.02, 0.001, 0.002, 0.0]), None, matrix)
    np.testing.assert_allclose(views.images[1].numpy(), expected, atol=1e-6)
    half = read_nerfstudio(tmp_path / "ns", downscale=2)
    assert half.images.shape == (3, 20, 30, 3)
    assert (half.intrinsics.fx, half.intrinsics.cx) == (25.0, 14.0)  # corner 29 -> 14.5 at half size -> 14.0


def test_nerfstudio_per_frame_intrinsics_and_refusals(tmp_path: Path) -> None:
    images = [np.zeros((8, 10, 3), np.uint8)] * 2
    frames = [dict(f, fl_x=9.0, w=10, h=8) for f in _frames(2)]
    views = read_nerfstudio(_write_nerfstudio(tmp_path / "a", {}, frames, images))
    assert views.intrinsics.fx == views.intrinsics.fy == 9.0
    assert (views.intrinsics.cx, views.intrinsics.cy) == (4.5, 3.5)  # no cx, cy: the centre of the 10x8 image
    with pytest.raises(ValueError, match="no intrinsics"):
        read_nerfstudio(_write_nerfstudio(tmp_path / "b", {"w": 10, "h": 8}, _frames(2), images))
    mixed = [np.zeros((8, 10, 3), np.uint8), np.zeros((9, 10, 3), np.uint8)]
    with pytest.raises(ValueError, match="frame_001.png is 10x9"):
        read_nerfstudio(_write_nerfstudio(tmp_path / "c", {"fl_x": 9.0, "w": 10, "h": 8}, _frames(2), mixed))
    nan_frames = _frames(2)
    nan_frames[1]["transform_matrix"][0][0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        read_nerfstudio(_write_nerfstudio(tmp_path / "d", {"fl_x": 9.0, "w": 10, "h": 8}, nan_frames, images))
    missing = _frames(2)
    path = _write_nerfstudio(tmp_path / "e", {"fl_x": 9.0, "w": 10, "h": 8}, missing, images)
    (path.parent / "frame_001.png").unlink()
    with pytest.raises(FileNotFoundError, match="frame_001.png"):
        read_nerfstudio(path)


@pytest.mark.parametrize("model", ["OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE624"])
def test_nerfstudio_refuses_cameras_that_are_not_perspective(tmp_path: Path, model: str) -> None:
    images = [np.zeros((8, 10, 3), np.uint8)] * 2
    path = _write_nerfstudio(tmp_path / "ns", {"camera_model": model, "fl_x": 9.0, "w": 10, "h": 8, "k1": 0.1}, _frames(2), images)
    with pytest.raises(ValueError, match=rf"transforms\.json: frame frame_000\.png has camera_model '{model}': expected a perspective camera"):
        read_nerfstudio(path)
    per_frame = [dict(f, camera_model=model) if i == 1 else f for i, f in enumerate(_frames(2))]
    with pytest.raises(ValueError, match=rf"frame frame_001\.png has camera_model '{model}'"):
        read_nerfstudio(_write_nerfstudio(tmp_path / "frame", {"camera_model": "OPENCV", "fl_x": 9.0, "w": 10, "h": 8}, per_frame, images))


def test_nerfstudio_reads_perspective_models_and_refuses_k4(tmp_path: Path) -> None:
    images = [np.zeros((8, 10, 3), np.uint8)] * 2
    for model in ("PINHOLE", "OPENCV", "SIMPLE_RADIAL"):
        views = read_nerfstudio(_write_nerfstudio(tmp_path / model, {"camera_model": model, "fl_x": 9.0, "w": 10, "h": 8}, _frames(2), images))
        assert views.intrinsics.fx == 9.0
    with pytest.raises(ValueError, match="has k4=0.01: expected none or 0"):
        read_nerfstudio(_write_nerfstudio(tmp_path / "k4", {"camera_model": "OPENCV", "fl_x": 9.0, "w": 10, "h": 8, "k4": 0.01}, _frames(2), images))
