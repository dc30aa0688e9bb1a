"""LLFF reader: nerf-pytorch's normalisation against the original Loc-NeRF's logs, splits, refusals."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from locnerf.data import read_dataset, read_llff


def test_poses_match_the_original_locnerf_ground_truth(shared_data: Path) -> None:
    fern = read_llff(shared_data / "llff" / "fern", downscale=8)
    logs = sorted((shared_data / "locnerf_logs").glob("*/gt_fern_*_poses.npy"))
    assert len(logs) == 10
    for log in logs:
        frame = int(log.name.split("_")[2])
        np.testing.assert_allclose(fern.T_world_cam[frame].numpy(), np.load(log), atol=1e-5, err_msg=str(log))


def test_images_intrinsics_and_normalisation(shared_data: Path) -> None:
    fern = read_llff(shared_data / "llff" / "fern", downscale=8)
    assert fern.images.shape == (20, 378, 504, 3)
    assert 0.0 <= float(fern.images.min()) and float(fern.images.max()) <= 1.0
    assert fern.intrinsics.fx == pytest.approx(3260.52633 / 8, rel=1e-4)
    # LLFF's principal point is the image centre: (W - 1)/2, (H - 1)/2 with pixel centres at integers.
    assert (fern.intrinsics.cx, fern.intrinsics.cy) == (251.5, 188.5)
    assert fern.normalization.ndc
    # nerf-pytorch scales by 1 / (0.75 · min near bound): the smallest near bound becomes 1/0.75.
    raw = np.load(shared_data / "llff" / "fern" / "poses_bounds.npy")
    assert fern.normalization.scale == pytest.approx(1.0 / (0.75 * raw[:, 15].min()))
    # The recorded transform maps scaled data-set camera centres onto the map-frame centres.
    T = torch.tensor(fern.normalization.T_map_dataset, dtype=torch.float64)
    centres = torch.from_numpy(raw[:, :15].reshape(-1, 3, 5)[:, :, 3]) * fern.normalization.scale
    mapped = centres @ T[:3, :3].T + T[:3, 3]
    torch.testing.assert_close(mapped, fern.T_world_cam[:, :3, 3], atol=1e-9, rtol=0)


def test_holdout_every_eighth_image(shared_data: Path) -> None:
    train = read_dataset(shared_data / "llff" / "fern", split="train")
    test = read_dataset(shared_data / "llff" / "fern", split="test")
    assert test.indices == [0, 8, 16]
    assert len(train) == 17 and not set(train.indices) & set(test.indices)
    assert test.names == ["image000", "image008", "image016"]


def _small_llff_copy(shared_data: Path, tmp_path: Path, images: int = 3) -> Path:
    folder = tmp_path / "scene"
    (folder / "images_8").mkdir(parents=True)
    source = shared_data / "llff" / "fern"
    np.save(folder / "poses_bounds.npy", np.load(source / "poses_bounds.npy")[:images])
    for path in sorted((source / "images_8").iterdir())[:images]:
        shutil.copy(path, folder / "images_8" / path.name)
    return folder


def test_refuses_mismatched_counts(shared_data: Path, tmp_path: Path) -> None:
    folder = _small_llff_copy(shared_data, tmp_path)
    np.save(folder / "poses_bounds.npy", np.load(folder / "poses_bounds.npy")[:2])
    with pytest.raises(ValueError, match="2 poses but .* 3 images"):
        read_llff(folder)


def test_refuses_nan_pose(shared_data: Path, tmp_path: Path) -> None:
    folder = _small_llff_copy(shared_data, tmp_path)
    poses = np.load(folder / "poses_bounds.npy")
    poses[1, 3] = np.nan
    np.save(folder / "poses_bounds.npy", poses)
    with pytest.raises(ValueError, match="row 1 holds a NaN"):
        read_llff(folder)


def test_refuses_empty_and_missing_folders(shared_data: Path, tmp_path: Path) -> None:
    folder = _small_llff_copy(shared_data, tmp_path)
    for path in (folder / "images_8").iterdir():
        path.unlink()
    with pytest.raises(FileNotFoundError, match="no images"):
        read_llff(folder)
    with pytest.raises(FileNotFoundError, match="poses_bounds.npy not found"):
        read_llff(tmp_path)
    with pytest.raises(ValueError, match="expected poses_bounds.npy"):
        read_dataset(tmp_path)


def test_refuses_images_of_mixed_size(shared_data: Path, tmp_path: Path) -> None:
    import cv2

    folder = _small_llff_copy(shared_data, tmp_path)
    path = sorted((folder / "images_8").iterdir())[1]
    cv2.imwrite(str(path), np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(ValueError, match=f"{path.name} has size 12x10"):
        read_llff(folder)
