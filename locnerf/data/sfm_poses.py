"""The SfM pseudo ground truth of 7-Scenes (Brachmann et al., ICCV 2021): ``pgt_sfm/*_sfm_pgt.txt``.

Each line is ``rgb_file qw qx qy qz tx ty tz f``: the **colour** camera's world-to-camera pose
(COLMAP's convention, ``p_cam = R(q) · p_world + t``, quaternion scalar-first, OpenCV camera axes,
metres) of the frame ``rgb_file`` names (``seq-01/frame-000650.color.png``), and the colour camera's
focal length ``f`` in pixels at 640×480 re-estimated by the reconstruction. Its world frame is the
reconstruction's own, not KinectFusion's (the ``dslam`` poses of ``frame-NNNNNN.pose.txt``).

:func:`read_sfm_poses` parses the files into camera-to-world poses (OpenCV axes, float64);
:func:`sfm_pose_of` finds a frame's line: by its sequence folder and frame number, else by the frame
number alone where that number is unique in the files (a folder that re-split one original sequence
into two, as ``7scenes_redkitchen`` here does, keeps the frame numbers).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from locnerf.errors import DatasetError
from locnerf.geometry.averaging import project_to_rotation
from locnerf.geometry.se3 import pose_inverse
from locnerf.geometry.similarity import fit_similarity
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

POSE_SOURCES = ("dslam", "sfm")
"""``--poses`` choices: the data set's own ``frame-NNNNNN.pose.txt`` (KinectFusion), or the SfM pseudo ground truth."""
PoseSource = Literal["dslam", "sfm"]
"""A configuration field naming one of :data:`POSE_SOURCES`."""
SFM_FOLDER = "pgt_sfm"
SFM_PATTERN = "*_sfm_pgt.txt"
QUATERNION_TOLERANCE = 1e-3
"""Largest accepted | |q| - 1 | (the files print six digits)."""
POSES_METADATA_KEY = "poses"
"""Map metadata key naming the pose source a map was built from (absent: ``dslam``)."""

_FRAME = re.compile(r"(?:(seq-\d+)/)?frame-(\d+)\.color\.\w+")


@dataclass(frozen=True)
class SfmPose:
    """One frame of the SfM pseudo ground truth.

    Attributes:
        T_world_cam: (4, 4) float64 camera-to-world pose of the colour camera, OpenCV axes, metres.
        focal: the colour camera's focal length, pixels at the file's image size (640×480).
        source: ``file:line`` it was read from.
    """

    T_world_cam: np.ndarray
    focal: float
    source: str


def check_pose_source(name: str) -> str:
    """``name`` if it is one of :data:`POSE_SOURCES`.

    Raises:
        DatasetError: naming the value and the choices.
    """
    if name not in POSE_SOURCES:
        raise DatasetError(f"--poses {name!r}: expected one of {', '.join(POSE_SOURCES)} (dslam: the data set's frame-NNNNNN.pose.txt; sfm: {SFM_FOLDER}/)")
    return name


def sfm_pose_files(folder: Path) -> list[Path]:
    """The ``pgt_sfm/*_sfm_pgt.txt`` files of a 7-Scenes scene folder, sorted.

    Raises:
        FileNotFoundError: naming the path looked in.
    """
    files = sorted((folder / SFM_FOLDER).glob(SFM_PATTERN))
    if not files:
        raise FileNotFoundError(
            f"{folder / SFM_FOLDER / SFM_PATTERN}: no such file (--poses sfm needs the SfM pseudo ground truth of Brachmann et al., "
            "lines 'rgb_file qw qx qy qz tx ty tz f')"
        )
    return files


def _pose_of_line(fields: list[str], where: str) -> tuple[np.ndarray, float]:
    try:
        values = np.array([float(x) for x in fields], dtype=np.float64)
    except ValueError:
        raise DatasetError(f"{where}: {' '.join(fields)!r}, expected 8 numbers 'qw qx qy qz tx ty tz f'") from None
    if not np.isfinite(values).all():
        raise DatasetError(f"{where}: non-finite value in {' '.join(fields)!r}")
    quaternion, translation, focal = values[:4], values[4:7], float(values[7])
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise DatasetError(f"{where}: quaternion of norm {norm:.6f}, expected a unit quaternion (within {QUATERNION_TOLERANCE})")
    if focal <= 0:
        raise DatasetError(f"{where}: focal length {focal}, expected > 0 pixels")
    w, x, y, z = quaternion / norm
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = rotation.T  # camera-to-world: the inverse of p_cam = R p_world + t
    T_world_cam[:3, 3] = -rotation.T @ translation
    return T_world_cam, focal


def read_sfm_poses(files: list[Path]) -> dict[str, SfmPose]:
    """Every line of the SfM pseudo-ground-truth ``files``, keyed by ``seq-NN/frame-NNNNNN``.

    Raises:
        DatasetError: naming the file and line of a line that is not ``rgb_file`` and 8 numbers, a
            quaternion that is not unit, a focal length <= 0, or a frame named twice.
    """
    poses: dict[str, SfmPose] = {}
    for path in files:
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            fields = line.split()
            if not fields or fields[0].startswith("#"):
                continue
            where = f"{path}:{number}"
            match = _FRAME.fullmatch(fields[0])
            if len(fields) != 9 or match is None:
                raise DatasetError(f"{where}: {line.strip()!r}, expected 'seq-NN/frame-NNNNNN.color.png qw qx qy qz tx ty tz f'")
            key = f"{match.group(1) or ''}/frame-{int(match.group(2)):06d}"
            if key in poses:
                raise DatasetError(f"{where}: frame {fields[0]} already given at {poses[key].source}")
            T_world_cam, focal = _pose_of_line(fields[1:], where)
            poses[key] = SfmPose(T_world_cam, focal, where)
    return poses


def sfm_pose_of(poses: dict[str, SfmPose], sequence: str, frame: int, files: list[Path], by_number: dict[int, list[SfmPose]] | None = None) -> SfmPose:
    """The pose of ``sequence``'s (``seq-NN``) frame number ``frame``: its own line, else the line of that
    frame number where exactly one sequence has it (``by_number``: the lines grouped by frame number, to look up many frames).

    Raises:
        DatasetError: naming the frame and the files when no line (or more than one) fits.
    """
    key = f"{sequence}/frame-{frame:06d}"
    if key in poses:
        return poses[key]
    candidates = by_number.get(frame, []) if by_number is not None else [pose for name, pose in poses.items() if name.endswith(key[key.index("/") :])]
    if len(candidates) != 1:
        found = "no line" if not candidates else f"{len(candidates)} lines of other sequences"
        raise DatasetError(f"{sequence}/frame-{frame:06d}: {found} in {', '.join(map(str, files))}; expected one line for each frame read")
    return candidates[0]


def rotated_axis(rotation: np.ndarray, axis: tuple[float, float, float]) -> tuple[float, float, float]:
    """``rotation @ axis`` as a unit 3-tuple."""
    value = rotation @ np.asarray(axis, dtype=np.float64)
    value = value / max(float(np.linalg.norm(value)), math.ulp(1.0))
    return (float(value[0]), float(value[1]), float(value[2]))


SFM_IMAGE_WIDTH = 640
"""Image width (px) at which the files' focal lengths hold."""


def sfm_poses_of(folder: Path, stems: list[Path], intrinsics: PinholeIntrinsics) -> tuple[np.ndarray, PinholeIntrinsics]:
    """(K, 4, 4) float64 camera-to-world colour-camera poses (OpenCV axes) of the frames ``stems``
    (``seq-NN/frame-NNNNNN`` paths), and ``intrinsics`` with the files' focal length (scaled to its width).

    Raises:
        FileNotFoundError / DatasetError: no pose files; a frame without a line; frames of different focal lengths.
    """
    files = sfm_pose_files(folder)
    table = read_sfm_poses(files)
    by_number: dict[int, list[SfmPose]] = {}
    for name, pose in table.items():
        by_number.setdefault(int(name.rsplit("-", 1)[1]), []).append(pose)
    chosen = [sfm_pose_of(table, stem.parent.name, int(stem.name.split("-")[-1]), files, by_number) for stem in stems]
    focals = sorted({pose.focal for pose in chosen})
    if len(focals) != 1:
        raise DatasetError(f"{files[0]}: the frames read have focal lengths {focals}; expected one colour camera")
    focal = focals[0] * intrinsics.width / SFM_IMAGE_WIDTH
    return np.stack([pose.T_world_cam for pose in chosen]), intrinsics.model_copy(update={"fx": focal, "fy": focal})


def sfm_up_axis(sfm: np.ndarray, dslam: np.ndarray, up: tuple[float, float, float]) -> tuple[float, float, float]:
    """The up axis ``up`` of the dSLAM world (its gravity file) in the SfM world: rotated by the
    similarity fitted on the two sets of camera centres (``sfm``, ``dslam``: (K, 4, 4) camera-to-world
    of the same frames; every frame of the scene, so that each split gets the same axis)."""
    try:
        similarity = fit_similarity(dslam[:, :3, 3], sfm[:, :3, 3])
        rotation = similarity.rotation
        logger.info("SfM world: similarity to the dSLAM world over %d camera centres, scale %.4f", len(sfm), similarity.scale)
    except ValueError as error:  # centres that span no plane (a camera that barely moved): the orientations' mean rotation
        logger.warning("%s; the up axis follows the mean rotation between the two ground truths' orientations", error)
        rotation = project_to_rotation(torch.from_numpy(np.einsum("kij,klj->il", sfm[:, :3, :3], dslam[:, :3, :3]))).numpy()
    return rotated_axis(rotation, up)


def sfm_depth_offset(T_depth_colour: torch.Tensor | None) -> torch.Tensor:
    """(4, 4) float64 ``T_cam_depth`` of colour-camera poses: the inverse of a calibration ``T_depth_colour``,
    or the identity (depth camera taken at the colour camera) when there is none."""
    if T_depth_colour is None:
        logger.warning("SfM poses without a colour-camera calibration: the depth camera is taken at the colour camera's pose")
        return torch.eye(4, dtype=torch.float64)
    return pose_inverse(T_depth_colour.to(torch.float64))
