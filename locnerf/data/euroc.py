"""EuRoC MAV folders: a stamped camera stream, its calibration and the ground-truth body trajectory.

Layout (ASL format): ``<root>/mav0/<camera>/data.csv`` (``#timestamp [ns],filename``) with images in
``<camera>/data/``, ``<camera>/sensor.yaml`` (pinhole ``intrinsics: [fu, fv, cu, cv]``,
``radial-tangential`` ``distortion_coefficients: [k1, k2, p1, p2]``, ``resolution: [w, h]`` and
``T_BS``, the camera-to-body transform), and the ground truth either as
``mav0/state_groundtruth_estimate0/data.csv`` (``ns, px, py, pz, qw, qx, qy, qz, ...``) or as a TUM
text file (``s tx ty tz qx qy qz qw``; ``<root>/groundtruth_tum/*.txt`` is found by itself). The
ground truth is the body (IMU) frame in the world; camera poses are ``T_world_body · T_BS``. Stamps
are kept as they are (seconds since the epoch, float64).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from locnerf.data.image_files import read_rgb
from locnerf.errors import DatasetError
from locnerf.geometry.quaternion import quaternion_to_matrix
from locnerf.render.camera import PinholeIntrinsics

NANOSECONDS = 1e9


@dataclass(frozen=True)
class EurocCamera:
    """One camera's calibration: the distorted model and the camera-to-body transform."""

    intrinsics: PinholeIntrinsics
    """fx, fy, cx, cy at the stored resolution (images are undistorted onto the same matrix)."""
    distortion: np.ndarray
    """(4,) radial-tangential k1, k2, p1, p2."""
    T_body_cam: torch.Tensor
    """(4, 4) float64, OpenCV camera axes."""


@dataclass(frozen=True)
class EurocSequence:
    """A camera stream with the ground truth of the body that carries it."""

    root: Path
    camera: EurocCamera
    image_stamps: np.ndarray
    """(K,) float64 seconds, increasing."""
    image_paths: list[Path]
    truth_stamps: np.ndarray
    """(G,) float64 seconds, increasing."""
    T_world_body: torch.Tensor
    """(G, 4, 4) float64."""

    def read_image(self, index: int, downscale: float = 1.0) -> np.ndarray:
        """Frame ``index`` undistorted, as (H, W, 3) uint8 RGB (grey cameras give three equal channels)."""
        raw = read_rgb(self.image_paths[index])
        k = self.camera.intrinsics
        matrix = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
        undistorted = cv2.undistort(raw, matrix, self.camera.distortion)
        if downscale != 1.0:
            height, width = undistorted.shape[:2]
            undistorted = cv2.resize(undistorted, (round(width / downscale), round(height / downscale)), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(np.clip(undistorted * 255.0 + 0.5, 0, 255).astype(np.uint8))


def _yaml_numbers(storage: cv2.FileStorage, name: str, path: Path, count: int) -> np.ndarray:
    node = storage.getNode(name)
    if node.isMap():
        node = node.getNode("data")
    if node.empty() or node.size() != count:
        raise DatasetError(f"{path}: expected {count} numbers in '{name}'")
    return np.array([node.at(i).real() for i in range(count)], dtype=np.float64)


def read_camera(sensor_yaml: Path) -> EurocCamera:
    """Calibration from a EuRoC ``sensor.yaml`` (Kalibr's intrinsics are OpenCV's, pixel centres at
    integer coordinates, the library's convention: taken as they are).

    Raises:
        FileNotFoundError / DatasetError: naming the file and the missing or unsupported entry.
    """
    if not sensor_yaml.is_file():
        raise FileNotFoundError(f"{sensor_yaml}: no such file (the camera calibration)")
    storage = cv2.FileStorage(str(sensor_yaml), cv2.FILE_STORAGE_READ)
    model = storage.getNode("camera_model").string()
    if model != "pinhole":
        raise DatasetError(f"{sensor_yaml}: camera_model '{model}', expected 'pinhole'")
    distortion_model = storage.getNode("distortion_model").string()
    if distortion_model != "radial-tangential":
        raise DatasetError(f"{sensor_yaml}: distortion_model '{distortion_model}', expected 'radial-tangential'")
    fx, fy, cx, cy = _yaml_numbers(storage, "intrinsics", sensor_yaml, 4)
    width, height = _yaml_numbers(storage, "resolution", sensor_yaml, 2)
    T_body_cam = torch.from_numpy(_yaml_numbers(storage, "T_BS", sensor_yaml, 16).reshape(4, 4))
    intrinsics = PinholeIntrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=int(width), height=int(height))
    return EurocCamera(intrinsics, _yaml_numbers(storage, "distortion_coefficients", sensor_yaml, 4), T_body_cam)


def _numeric_rows(path: Path, delimiter: str | None, columns: int) -> np.ndarray:
    """(N, ≥columns) float64 rows of a text table, '#' comments skipped."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        rows = np.loadtxt(path, delimiter=delimiter, comments="#", ndmin=2, dtype=np.float64)
    except ValueError as error:
        raise DatasetError(f"{path}: not a numeric table ({error})") from error
    if rows.shape[0] < 2 or rows.shape[1] < columns:
        raise DatasetError(f"{path}: expected at least 2 rows of {columns} columns, got shape {rows.shape}")
    if not np.isfinite(rows[:, :columns]).all():
        raise DatasetError(f"{path}: NaN or infinite values")
    if (np.diff(rows[:, 0]) <= 0).any():
        raise DatasetError(f"{path}: stamps must increase")
    return rows


def _poses(positions: np.ndarray, quaternions_wxyz: np.ndarray) -> torch.Tensor:
    poses = torch.eye(4, dtype=torch.float64).repeat(len(positions), 1, 1)
    poses[:, :3, :3] = quaternion_to_matrix(torch.from_numpy(quaternions_wxyz))
    poses[:, :3, 3] = torch.from_numpy(positions)
    return poses


def read_groundtruth(path: Path) -> tuple[np.ndarray, torch.Tensor]:
    """Stamps (G,) seconds and body poses (G, 4, 4) from an ASL ``data.csv`` or a TUM ``.txt``."""
    if path.suffix == ".csv":
        rows = _numeric_rows(path, ",", 8)
        return rows[:, 0] / NANOSECONDS, _poses(rows[:, 1:4], rows[:, 4:8])
    rows = _numeric_rows(path, None, 8)
    return rows[:, 0], _poses(rows[:, 1:4], rows[:, [7, 4, 5, 6]])


def _default_groundtruth(root: Path) -> Path:
    asl = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    if asl.is_file():
        return asl
    tum = sorted((root / "groundtruth_tum").glob("*.txt"))
    if tum:
        return tum[0]
    raise FileNotFoundError(f"{root}: no ground truth (mav0/state_groundtruth_estimate0/data.csv or groundtruth_tum/*.txt)")


def read_euroc(root: str | Path, camera: str = "cam0", groundtruth: str | Path | None = None) -> EurocSequence:
    """Open a EuRoC folder (the one holding ``mav0``).

    Raises:
        FileNotFoundError / DatasetError: naming the file and the problem (missing list, calibration,
            images or ground truth; stamps not increasing; ground truth not covering the images).
    """
    root = Path(root)
    folder = root / "mav0" / camera
    listing = folder / "data.csv"
    if not listing.is_file():
        raise FileNotFoundError(f"{listing}: no such file (expected a EuRoC folder holding mav0/{camera}/data.csv)")
    entries = [line.split(",") for line in listing.read_text().splitlines() if line.strip() and not line.startswith("#")]
    if len(entries) < 2 or any(len(entry) != 2 for entry in entries):
        raise DatasetError(f"{listing}: expected at least 2 rows of 'timestamp [ns],filename'")
    stamps = np.array([int(entry[0]) for entry in entries], dtype=np.int64)
    if (np.diff(stamps) <= 0).any():
        raise DatasetError(f"{listing}: image stamps must increase")
    paths = [folder / "data" / entry[1].strip() for entry in entries]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{missing[0]}: no such image ({len(missing)} of {len(paths)} listed in {listing} are missing)")
    truth_stamps, T_world_body = read_groundtruth(Path(groundtruth) if groundtruth else _default_groundtruth(root))
    image_stamps = stamps / NANOSECONDS
    if truth_stamps[0] > image_stamps[-1] or truth_stamps[-1] < image_stamps[0]:
        raise DatasetError(
            f"{root}: the ground truth ({truth_stamps[0]:.3f}–{truth_stamps[-1]:.3f} s) does not overlap the images "
            f"({image_stamps[0]:.3f}–{image_stamps[-1]:.3f} s)"
        )
    return EurocSequence(root, read_camera(folder / "sensor.yaml"), image_stamps, paths, truth_stamps, T_world_body)
