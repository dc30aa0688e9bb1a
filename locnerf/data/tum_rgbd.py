"""The TUM RGB-D benchmark layout (Sturm et al., IROS 2012): ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``.

Layout: ``rgb.txt`` and ``depth.txt`` list ``stamp filename`` per frame (``#`` comments), the files
under ``rgb/`` (8-bit colour PNG) and ``depth/`` (16-bit PNG, 5000 units per metre, 0 = no reading,
registered to the colour camera by the Kinect driver); ``groundtruth.txt`` is a TUM trajectory
(``stamp tx ty tz qx qy qz qw``, :mod:`locnerf.data.trajectory_files`) of the colour camera in the
motion-capture world, OpenCV camera axes, at its own (faster) rate.

Association, as the benchmark's ``associate.py``: each colour frame takes the depth frame nearest in
time if it lies within :data:`MAX_DIFFERENCE` s, and the ground truth at its stamp (geodesic between
the samples around it, when they lie at most :data:`MAX_TRUTH_GAP` s apart); colour frames without
either are left out (logged). Frames keep the order of ``rgb.txt``.

Camera: ``camera-intrinsics.txt`` (a 3×3 matrix) when present, else the benchmark's default for
its registered images (fx = fy = 525, cx = 319.5, cy = 239.5 at 640×480). Depth and colour share it
at full size; the colour image is area-resized by ``downscale``, the depth image subsampled (every
``downscale``-th pixel), so each keeps its own matrix (:class:`~locnerf.render.camera.PinholeIntrinsics`).
Splits: ``all``; ``test`` every 8th associated frame, ``train`` the others (as LLFF and nerfstudio).
Scale: metres, identity transform; the up axis is the motion-capture world's +z.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from locnerf.data.image_files import read_rgb, stack_same_size
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import NEAR_M, DepthUnits, read_depth, scene_box
from locnerf.data.trajectory_files import read_trajectory, sample_trajectory
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

TUM_DEPTH = DepthUnits(5000.0, (0,), "1/5000 m", "in units of 1/5000 m (5000 per metre)")
MAX_DIFFERENCE = 0.02
"""Largest colour-depth stamp difference of an associated pair, seconds (associate.py's default)."""
MAX_TRUTH_GAP = 0.1
"""Longest spacing of ground-truth samples interpolated across, seconds."""
DEFAULT_INTRINSICS = PinholeIntrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
DEFAULT_DOWNSCALE = 4
TEST_EVERY = 8
UP = (0.0, 0.0, 1.0)
SPLITS = ("train", "test", "all")


def is_tum_rgbd(folder: Path) -> bool:
    """Whether ``folder`` holds the three TUM RGB-D lists."""
    return all((folder / name).is_file() for name in ("rgb.txt", "depth.txt", "groundtruth.txt"))


def read_file_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """Stamps (K,) float64 seconds and file names of a TUM ``rgb.txt`` / ``depth.txt``.

    Raises:
        FileNotFoundError / DatasetError: naming the file, the line and what was expected.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (a TUM RGB-D list of 'stamp filename' lines)")
    stamps, names = [], []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        try:
            stamp = float(fields[0])
        except ValueError:
            stamp = float("nan")
        if len(fields) != 2 or not np.isfinite(stamp):
            raise DatasetError(f"{path}, line {number}: {line!r}, expected 'stamp filename' (a number in seconds and a path)")
        if stamps and stamp <= stamps[-1]:
            raise DatasetError(f"{path}, line {number}: stamp {stamp} is not after {stamps[-1]}; expected strictly increasing stamps")
        stamps.append(stamp)
        names.append(fields[1])
    if not stamps:
        raise DatasetError(f"{path}: no frames (expected 'stamp filename' lines)")
    return np.asarray(stamps), names


def associate(colour: np.ndarray, depth: np.ndarray, max_difference: float = MAX_DIFFERENCE) -> np.ndarray:
    """(K,) index of the depth stamp nearest to each colour stamp, -1 where none lies within ``max_difference`` s."""
    after = np.clip(np.searchsorted(depth, colour), 1, len(depth) - 1) if len(depth) > 1 else np.zeros(len(colour), dtype=int)
    before = np.maximum(after - 1, 0)
    nearest = np.where(np.abs(depth[before] - colour) <= np.abs(depth[after] - colour), before, after)
    return np.where(np.abs(depth[nearest] - colour) <= max_difference, nearest, -1)


def _intrinsics(folder: Path, width: int, height: int) -> PinholeIntrinsics:
    """The full-size camera of ``width`` × ``height`` images: ``camera-intrinsics.txt``, else the benchmark's 640×480 default."""
    path = folder / "camera-intrinsics.txt"
    if not path.is_file():
        if (width, height) != (DEFAULT_INTRINSICS.width, DEFAULT_INTRINSICS.height):
            raise DatasetError(f"{folder}: images of {width}x{height} and no camera-intrinsics.txt; expected 640x480 or a 3x3 camera matrix in that file")
        return DEFAULT_INTRINSICS
    matrix = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
        raise DatasetError(f"{path}: expected a finite 3x3 camera matrix, got shape {matrix.shape}")
    return PinholeIntrinsics(fx=matrix[0, 0], fy=matrix[1, 1], cx=matrix[0, 2], cy=matrix[1, 2], width=width, height=height)


def read_tum_rgbd(folder: str | Path, split: str = "train", downscale: int = DEFAULT_DOWNSCALE, stride: int = 1, depth: bool = True) -> PosedImages:
    """Read one split of a TUM RGB-D sequence folder.

    Args:
        folder: holds ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` and the images they name.
        split: ``train`` | ``test`` | ``all`` (see the module docstring).
        downscale: colour size divisor (area resize); the depth image is subsampled by the same factor.
        stride: keep every ``stride``-th frame of the split.
        depth: read the depth images.
    Returns:
        PosedImages in the motion-capture frame (metres, OpenGL camera axes), with ``depths`` (K, H, W)
        in metres and the (shared) camera as ``depth_intrinsics``.
    Raises:
        FileNotFoundError / DatasetError: naming the file (and line) and what was expected.
    """
    folder = Path(folder)
    if split not in SPLITS:
        raise DatasetError(f"split {split!r}: expected one of {', '.join(SPLITS)} for a TUM RGB-D folder ({folder})")
    if downscale < 1 or stride < 1:
        raise DatasetError(f"downscale={downscale}, stride={stride}: expected integers >= 1")
    colour_stamps, colour_names = read_file_list(folder / "rgb.txt")
    depth_stamps, depth_names = read_file_list(folder / "depth.txt")
    pairs = associate(colour_stamps, depth_stamps)
    truth, has_truth = sample_trajectory(read_trajectory(folder / "groundtruth.txt", "tum"), colour_stamps, MAX_TRUTH_GAP, what="rgb.txt")
    keep = np.flatnonzero((pairs >= 0) & has_truth)
    if len(keep) < len(colour_stamps):
        logger.info("%s: %d of %d colour frames without depth or ground truth left out", folder, len(colour_stamps) - len(keep), len(colour_stamps))
    if split == "test":
        keep = keep[::TEST_EVERY]
    elif split == "train":
        keep = np.delete(keep, np.arange(0, len(keep), TEST_EVERY))
    keep = keep[::stride]
    if not len(keep):
        raise DatasetError(f"{folder}: no {split} frames with depth within {MAX_DIFFERENCE} s and ground truth")
    paths = [folder / colour_names[i] for i in keep]
    images = stack_same_size([read_rgb(p, float(downscale)) for p in tqdm(paths, desc=f"TUM RGB-D {split}", unit="frame", leave=False)], paths)
    full = _intrinsics(folder, images.shape[2] * downscale, images.shape[1] * downscale)
    camera = full.scaled(1.0 / downscale)  # area resize; the depth image, subsampled, has full.decimated(downscale)
    T_world_cam = opencv_to_opengl(truth[torch.from_numpy(keep)])
    depths = None
    if depth:
        depths = torch.from_numpy(np.stack([read_depth(folder / depth_names[pairs[i]], downscale, TUM_DEPTH) for i in keep]))
        if depths.shape[1:] != images.shape[1:3]:
            raise DatasetError(
                f"{folder / depth_names[pairs[keep[0]]]}: depth of {tuple(depths.shape[1:])} after ÷{downscale}, expected the colour's {images.shape[1:3]}"
            )
    depth_camera = full.decimated(downscale) if depth else None
    box = scene_box(T_world_cam, depths, depth_camera)
    far = float((box[1] - box[0]).norm())
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=T_world_cam,
        intrinsics=camera,
        near=NEAR_M,
        far=far,
        normalization=MapNormalization(near=NEAR_M, far=far, up=UP),
        names=[Path(colour_names[i]).stem for i in keep],
        scene_bounds=box,
        source=str(folder),
        indices=keep.tolist(),
        depths=depths,
        depth_intrinsics=depth_camera,
    )
