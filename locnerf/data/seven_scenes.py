"""Microsoft 7-Scenes RGB-D sequences: ``seq-NN/frame-NNNNNN.{color.png|color.jpg,depth.png,pose.txt}``.

Layout: ``TrainSplit.txt`` / ``TestSplit.txt`` name sequences (``sequence1`` -> ``seq-01/``); each
frame has a colour image (640×480), a depth image (uint16 millimetres, 0 or 65535 = no reading;
the full 640×480 or a subsampled integer fraction of it) and a 4×4 camera-to-world pose in metres
with OpenCV camera axes (x right, y down, z forward), converted here with ``opencv_to_opengl``.

Cameras: 7-Scenes ships no colour intrinsics; the customary fx = fy = 525, cx = 320, cy = 240 at
640×480 is the default (overridable). ``camera-intrinsics.txt``, where present, is the depth
camera's (585 px at 640×480; that value is the fallback). Colour and depth are not registered and
the poses are the depth camera's; as is usual practice the poses serve both, and each image keeps
its own camera: depth pixels become rays of the depth camera, never resampled onto the colour grid.
Both matrices are taken as OpenCV's (pixel centres at integers). Colour images are area-resized by
``downscale`` (``cx' = (cx + 0.5)/downscale - 0.5``: 79.625 at ÷4); depth images are subsampled
(every k-th pixel, ``cx' = cx/k``), see :class:`~locnerf.render.camera.PinholeIntrinsics`.

Scale: the map frame is the data set's world frame in metres (scale 1, identity transform). The
scene box holds the camera centres and the back-projected depth points (cameras look from inside
a room). ``gravity-direction.txt`` (a unit vector in the world frame, pointing down), where present,
gives the map's up axis; otherwise the 7-Scenes world's -y (KinectFusion frames are about y-down).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from locnerf.data.image_files import read_rgb, stack_same_size
from locnerf.data.posed_images import PosedImages
from locnerf.data.scene_bounds import BOUNDS_FRAMES, bounds_pixel_step, depth_points, percentile_box
from locnerf.data.sfm_poses import check_pose_source, sfm_depth_offset, sfm_poses_of, sfm_up_axis
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.averaging import project_to_rotation
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

COLOUR_INTRINSICS = PinholeIntrinsics(fx=525.0, fy=525.0, cx=320.0, cy=240.0, width=640, height=480)
"""The customary 7-Scenes colour camera at full resolution."""
DEPTH_FOCAL = 585.0
"""Depth camera focal length (px at 640×480) when ``camera-intrinsics.txt`` is absent."""
DEFAULT_DOWNSCALE = 4
SPLIT_FILES = {"train": ("TrainSplit.txt",), "test": ("TestSplit.txt",), "all": ("TrainSplit.txt", "TestSplit.txt")}
INVALID_DEPTH_MM = (0, 65535)
RIGID_TOLERANCE = 1e-3
"""Largest |RᵀR - I| entry of an accepted pose rotation (the data's own: 4e-4)."""
BOX_MARGIN_M = 0.1
NO_DEPTH_REACH_M = 2.0
"""Without depth, the box is the camera centres' box grown by this (a room seen from inside)."""
NEAR_M = 0.1
DEFAULT_UP = (0.0, -1.0, 0.0)


def sequence_folders(folder: Path, split: str) -> list[Path]:
    """The ``seq-XX`` folders a split names, in the order of its split files."""
    if split not in SPLIT_FILES:
        raise DatasetError(f"split {split!r}: expected one of {sorted(SPLIT_FILES)} for a 7-Scenes folder ({folder})")
    folders = []
    for name in SPLIT_FILES[split]:
        path = folder / name
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such file (a 7-Scenes split file naming 'sequenceN' lines)")
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        if not lines:
            raise DatasetError(f"{path}: empty split, expected at least one 'sequenceN' line")
        for line in lines:
            match = re.fullmatch(r"sequence(\d+)", line)
            if match is None:
                raise DatasetError(f"{path}: line {line!r}, expected 'sequenceN'")
            sequence = folder / f"seq-{int(match.group(1)):02d}"
            if not sequence.is_dir():
                raise FileNotFoundError(f"{path} names {line}: folder {sequence} not found")
            folders.append(sequence)
    return folders


def frame_stems(sequence: Path) -> list[Path]:
    """``seq-NN/frame-NNNNNN`` stems of a sequence's colour images, sorted."""
    stems = sorted({p.parent / p.name.split(".")[0] for p in sequence.glob("frame-*.color.*") if p.suffix.lower() in (".png", ".jpg", ".jpeg")})
    if not stems:
        raise FileNotFoundError(f"{sequence}: no frame-NNNNNN.color.png/.jpg images")
    return stems


def colour_path(stem: Path) -> Path:
    for suffix in (".color.png", ".color.jpg", ".color.jpeg"):
        path = stem.with_name(stem.name + suffix)
        if path.is_file():
            return path
    raise FileNotFoundError(f"{stem}.color.png: no such file (nor .jpg)")


def read_pose(path: Path) -> np.ndarray:
    """A rigid 4×4 camera-to-world pose (float64) from a 7-Scenes ``.pose.txt``.

    The files' rotations are orthonormal to a few 1e-4 only (KinectFusion's poses, printed with
    limited digits; redkitchen has determinants down to 0.9989). Within ``RIGID_TOLERANCE`` the
    rotation is replaced by the closest rotation (SVD) and the last row by 0 0 0 1, so that poses
    and the odometry composed from them pass the services' 1e-3 rigidity check exactly.

    Raises:
        FileNotFoundError / DatasetError: naming the file and what was expected.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (the frame's 4x4 camera-to-world pose)")
    try:
        pose = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as error:
        raise DatasetError(f"{path}: not a 4x4 table of numbers ({error})") from error
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise DatasetError(f"{path}: expected a finite 4x4 matrix, got shape {pose.shape}")
    rotation = pose[:3, :3]
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > RIGID_TOLERANCE or np.linalg.det(rotation) <= 0 or np.abs(pose[3] - (0.0, 0.0, 0.0, 1.0)).max() > RIGID_TOLERANCE:
        raise DatasetError(
            f"{path}: not a rigid transform (|RᵀR - I| = {error:.2e}, det {np.linalg.det(rotation):.3f}, "
            f"last row {pose[3].tolist()}); expected a rotation, a translation and the row 0 0 0 1"
        )
    pose[:3, :3] = project_to_rotation(torch.from_numpy(rotation)).numpy()
    pose[3] = (0.0, 0.0, 0.0, 1.0)
    return pose


@dataclass(frozen=True)
class DepthUnits:
    """How a uint16 depth PNG stores metres: ``per_metre`` units in a metre, the values that mean "no depth",
    and the unit's short and long names for messages."""

    per_metre: float
    invalid: tuple[int, ...]
    short: str
    long: str


MILLIMETRES = DepthUnits(1000.0, INVALID_DEPTH_MM, "mm", "millimetres")
"""7-Scenes' depth (the Kinect's 65535 marks no reading too)."""


def read_depth(path: Path, stride: int, units: DepthUnits = MILLIMETRES) -> np.ndarray:
    """(H/stride, W/stride) float32 metres from a uint16 depth PNG in ``units``, 0 where invalid
    (nearest subsampling: averaging would mix in the invalid zeros)."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise FileNotFoundError(f"{path}: no such file or not an image (the frame's uint16 depth in {units.short})")
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise DatasetError(f"{path}: {raw.dtype} image of shape {raw.shape}, expected single-channel uint16 {units.long}")
    depth = raw[::stride, ::stride]
    metres = depth.astype(np.float32) / units.per_metre
    metres[np.isin(depth, units.invalid)] = 0.0
    return metres


def _depth_ratio(colour: tuple[int, int], depth: tuple[int, int], path: Path) -> int:
    """Integer k with depth size = colour size / k; sizes as (width, height)."""
    ratio = colour[0] // depth[0] if depth[0] else 0
    if ratio < 1 or depth[0] * ratio != colour[0] or depth[1] * ratio != colour[1]:
        raise DatasetError(
            f"{path}: depth {depth[0]}x{depth[1]}, expected the colour size {colour[0]}x{colour[1]} divided by an integer (e.g. 320x240 for 640x480)"
        )
    return ratio


def depth_camera_of(folder: Path, colour: PinholeIntrinsics) -> PinholeIntrinsics:
    """The depth camera at the colour camera's full resolution (``camera-intrinsics.txt`` or 585 px)."""
    path = folder / "camera-intrinsics.txt"
    if not path.is_file():
        return PinholeIntrinsics(fx=DEPTH_FOCAL, fy=DEPTH_FOCAL, cx=colour.width / 2.0, cy=colour.height / 2.0, width=colour.width, height=colour.height)
    matrix = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
        raise DatasetError(f"{path}: expected a finite 3x3 camera matrix, got shape {matrix.shape}")
    return PinholeIntrinsics(fx=matrix[0, 0], fy=matrix[1, 1], cx=matrix[0, 2], cy=matrix[1, 2], width=colour.width, height=colour.height)


def _up_axis(folder: Path) -> tuple[float, float, float]:
    """Minus the gravity direction of ``gravity-direction.txt`` (world frame), or the default -y."""
    path = folder / "gravity-direction.txt"
    if not path.is_file():
        return DEFAULT_UP
    gravity = np.loadtxt(path, dtype=np.float64).reshape(-1)
    if gravity.shape != (3,) or not np.isfinite(gravity).all() or np.linalg.norm(gravity) < 1e-6:
        raise DatasetError(f"{path}: expected 3 finite numbers (the gravity direction), got {gravity.tolist()}")
    up = -gravity / np.linalg.norm(gravity)
    return (float(up[0]), float(up[1]), float(up[2]))


def scene_box(T_world_cam: torch.Tensor, depths: torch.Tensor | None, camera: PinholeIntrinsics | None) -> torch.Tensor:
    """(2, 3) float64 box around the camera centres and the depth points (robust percentiles), plus a margin."""
    centres = T_world_cam[:, :3, 3].double()
    low, high = centres.amin(0), centres.amax(0)
    if depths is None or camera is None:
        return torch.stack((low - NO_DEPTH_REACH_M, high + NO_DEPTH_REACH_M))
    frames = max(1, len(depths) // BOUNDS_FRAMES)
    step = bounds_pixel_step(camera.width, camera.height)
    points = depth_points(depths[::frames, ::step, ::step], T_world_cam[::frames], camera.decimated(step))
    if len(points):
        quantiles = percentile_box(points)
        low, high = torch.minimum(low, quantiles[0]), torch.maximum(high, quantiles[1])
    return torch.stack((low - BOX_MARGIN_M, high + BOX_MARGIN_M))


def read_seven_scenes(
    folder: str | Path,
    split: str = "train",
    downscale: int = DEFAULT_DOWNSCALE,
    stride: int = 1,
    intrinsics: PinholeIntrinsics = COLOUR_INTRINSICS,
    depth: bool = True,
    poses: str = "dslam",
    T_depth_colour: torch.Tensor | None = None,
) -> PosedImages:
    """Read one split of a 7-Scenes scene.

    Args:
        folder: holds ``TrainSplit.txt``, ``TestSplit.txt`` and the ``seq-XX`` folders.
        split: ``train`` | ``test`` | ``all`` (both).
        downscale: colour image size divisor (area resize); depth images are subsampled to the
            nearest size at or above the colour size (every ``downscale / k``-th pixel, k the
            colour-to-depth size ratio).
        stride: keep every ``stride``-th frame of the split (consecutive 30 Hz frames overlap a lot).
        intrinsics: the colour camera at the stored image size.
        depth: read the depth images (skipped when the frames have none).
        poses: ``dslam``, the frames' ``.pose.txt`` (the depth camera, KinectFusion's world); ``sfm``, the
            SfM pseudo ground truth of ``pgt_sfm/`` (:mod:`locnerf.data.sfm_poses`): the colour camera's
            poses in the reconstruction's world, its focal length replacing ``intrinsics``' (same centre).
        T_depth_colour: ``sfm`` only: (4, 4) the colour camera's pose in the depth camera's frame (a map's
            calibration, :mod:`locnerf.data.colour_camera`, metres); the depth camera is then posed at
            ``T_world_cam · T_depth_colour⁻¹`` (``T_cam_depth``). None: at the colour camera (identity).
    Returns:
        PosedImages in the world frame (metres, OpenGL camera axes), with ``depths`` (K, Hd, Wd)
        in metres and the depth camera when the frames have depth images.
    Raises:
        FileNotFoundError / DatasetError: naming the file and what was expected (unknown or empty
            split, missing pose, non-rigid pose, image or depth sizes that do not fit).
    """
    folder = Path(folder)
    if downscale < 1 or stride < 1:
        raise DatasetError(f"downscale={downscale}, stride={stride}: expected integers >= 1")
    every = [stem for sequence in sequence_folders(folder, "all") for stem in frame_stems(sequence)]
    position = {stem: i for i, stem in enumerate(every)}
    stems = [stem for sequence in sequence_folders(folder, split) for stem in frame_stems(sequence)][::stride]
    if check_pose_source(poses) == "sfm":
        pose_table, intrinsics = sfm_poses_of(folder, stems, intrinsics)
    else:
        pose_table = np.stack([read_pose(stem.with_name(stem.name + ".pose.txt")) for stem in stems])
    paths = [colour_path(stem) for stem in stems]
    images = stack_same_size([read_rgb(p, float(downscale)) for p in tqdm(paths, desc=f"7-Scenes {split}", unit="frame", leave=False)], paths)
    full = (images.shape[2] * downscale, images.shape[1] * downscale)
    if (round(full[0]), round(full[1])) != (intrinsics.width, intrinsics.height):
        raise DatasetError(f"{paths[0]}: images about {full[0]}x{full[1]}, expected {intrinsics.width}x{intrinsics.height} for the colour intrinsics given")
    camera = intrinsics.scaled(1.0 / downscale)
    T_world_cam = opencv_to_opengl(torch.from_numpy(pose_table))
    depth_paths = [stem.with_name(stem.name + ".depth.png") for stem in stems]
    depths, depth_camera = None, None
    if depth and any(p.is_file() for p in depth_paths):
        first = cv2.imread(str(depth_paths[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise FileNotFoundError(f"{depth_paths[0]}: no such file or not an image (the frame's uint16 depth in mm)")
        ratio = _depth_ratio((intrinsics.width, intrinsics.height), (first.shape[1], first.shape[0]), depth_paths[0])
        depth_stride = max(1, downscale // ratio)
        stack = [read_depth(path, depth_stride) for path in depth_paths]
        for path, metres in zip(depth_paths, stack):
            if metres.shape != stack[0].shape:
                raise DatasetError(
                    f"{path}: depth of size {metres.shape[1] * depth_stride}x{metres.shape[0] * depth_stride}, "
                    f"expected {first.shape[1]}x{first.shape[0]} like {depth_paths[0]}"
                )
        depths = torch.from_numpy(np.stack(stack))
        # Stored depth smaller than colour is every ratio-th pixel of the full frame, read every depth_stride-th.
        depth_camera = depth_camera_of(folder, intrinsics).decimated(ratio * depth_stride)
    box = scene_box(T_world_cam, depths, depth_camera)
    far = float((box[1] - box[0]).norm())
    up = _up_axis(folder)
    if poses == "sfm":
        up = sfm_up_axis(sfm_poses_of(folder, every, intrinsics)[0], np.stack([read_pose(stem.with_name(stem.name + ".pose.txt")) for stem in every]), up)
    normalization = MapNormalization(near=NEAR_M, far=far, up=up)
    logger.info(
        "7-Scenes %s %s (%s poses): %d frames %dx%d, depth %s, box %s",
        folder,
        split,
        poses,
        len(stems),
        camera.width,
        camera.height,
        "none" if depths is None else f"{depths.shape[2]}x{depths.shape[1]}",
        box.numpy().round(2).tolist(),
    )
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=T_world_cam,
        intrinsics=camera,
        near=NEAR_M,
        far=far,
        normalization=normalization,
        names=[f"{stem.parent.name}/{stem.name}" for stem in stems],
        scene_bounds=box,
        source=str(folder),
        indices=[position[stem] for stem in stems],
        depths=depths,
        depth_intrinsics=depth_camera,
        T_cam_depth=None if poses == "dslam" or depths is None else sfm_depth_offset(T_depth_colour),
    )
