"""LLFF forward-facing captures: ``poses_bounds.npy`` + ``images[_N]/``, normalised as nerf-pytorch does.

``poses_bounds.npy`` holds one row of 17 numbers per image (sorted file order): a 3×5 matrix
``[R | t | (H, W, f)]`` with camera axes (down, right, backwards), then the near and far depth
bounds. nerf-pytorch (and therefore the original Loc-NeRF) turns that into its map frame by:

1. reordering the camera axes to (right, up, backwards) = OpenGL;
2. scaling translations and bounds by ``sc = 1 / (bd_factor · min(near bounds))``, bd_factor 0.75;
3. recentring: left-multiplying every pose by the inverse of the "average pose" (mean centre,
   summed z axis, summed y axis as up, re-orthonormalised).

The same transform (scale, then ``inv(average pose)``) is recorded as the map normalisation.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch

from locnerf.data.image_files import read_rgb, stack_same_size
from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

BD_FACTOR = 0.75
HOLDOUT_EVERY = 8
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
NDC_CUBE = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
"""The scene bounds of an NDC map: its normalised device coordinates' cube."""


def _normalize(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def average_pose(poses: np.ndarray) -> np.ndarray:
    """nerf-pytorch's average camera: poses (K, 3, 4) -> (4, 4) with mean centre, mean viewing axis."""
    centre = poses[:, :3, 3].mean(0)
    z_axis = _normalize(poses[:, :3, 2].sum(0))
    up = poses[:, :3, 1].sum(0)
    x_axis = _normalize(np.cross(up, z_axis))
    y_axis = _normalize(np.cross(z_axis, x_axis))
    average = np.eye(4)
    average[:3, :4] = np.stack([x_axis, y_axis, z_axis, centre], axis=1)
    return average


def normalize_llff_poses(poses_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """nerf-pytorch's LLFF normalisation of ``poses_bounds.npy``'s rows (:func:`normalize_forward_facing`).

    Args:
        poses_bounds: (K, 17) rows of ``poses_bounds.npy``.
    Returns:
        as :func:`normalize_forward_facing`.
    """
    raw = poses_bounds[:, :15].reshape(-1, 3, 5).astype(np.float64)
    # (down, right, back) -> (right, up, back): columns [1, -0, 2].
    poses = np.concatenate([raw[:, :, 1:2], -raw[:, :, 0:1], raw[:, :, 2:4]], axis=2)
    return normalize_forward_facing(poses, poses_bounds[:, 15:17].astype(np.float64))


def normalize_forward_facing(poses: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """nerf-pytorch's forward-facing normalisation: scale by ``1 / (bd_factor · min near bound)``, then recentre.

    Args:
        poses: (K, 3, 4) OpenGL camera-to-world poses in the data set's world frame.
        bounds: (K, 2) each image's near and far depth bounds, the same units.
    Returns:
        T_world_cam (K, 4, 4) OpenGL camera-to-world in the map frame, bounds (K, 2) in map units,
        T_map_scaled (4, 4) the recentring applied after scaling, and the scale (map units per
        data-set unit).
    """
    poses = poses.astype(np.float64).copy()
    scale = 1.0 / (bounds.min() * BD_FACTOR)
    poses[:, :, 3] *= scale
    bounds = bounds * scale
    T_map_scaled = np.linalg.inv(average_pose(poses))
    homogeneous = np.tile(np.eye(4), (len(poses), 1, 1))
    homogeneous[:, :3, :4] = poses
    return T_map_scaled @ homogeneous, bounds, T_map_scaled, scale


def forward_facing_normalization(T_map_scaled: np.ndarray, scale: float, bounds: np.ndarray) -> MapNormalization:
    """The NDC map normalisation of :func:`normalize_forward_facing`'s outputs (``bounds`` in map units)."""
    return MapNormalization(T_map_dataset=T_map_scaled.tolist(), scale=scale, ndc=True, near=float(bounds.min() * 0.9), far=float(bounds.max()))


def image_folder(folder: Path, downscale: int) -> tuple[Path, float]:
    """The folder to read and the extra resize factor: ``images_<d>`` if present, else ``images`` resized."""
    exact = folder / f"images_{downscale}" if downscale != 1 else folder / "images"
    if exact.is_dir():
        return exact, 1.0
    full = folder / "images"
    if full.is_dir():
        return full, float(downscale)
    raise FileNotFoundError(f"LLFF folder {folder}: neither {exact.name}/ nor images/ exists")


def read_llff(folder: str | Path, downscale: int = 8, split: str = "all", holdout_every: int = HOLDOUT_EVERY) -> PosedImages:
    """Read an LLFF capture.

    Args:
        folder: holds ``poses_bounds.npy`` and ``images_<downscale>/`` (or ``images/``).
        downscale: image size divisor relative to the full-resolution ``hwf`` in the poses.
        split: ``all``, ``train`` (all but every ``holdout_every``-th image) or ``test`` (every
            ``holdout_every``-th, starting at 0: nerf-pytorch's ``llffhold``).
        holdout_every: hold-out period.
    Returns:
        PosedImages in nerf-pytorch's normalised frame, NDC flag set, scene bounds = NDC cube.
    """
    folder = Path(folder)
    poses_file = folder / "poses_bounds.npy"
    if not poses_file.is_file():
        raise FileNotFoundError(f"LLFF folder {folder}: {poses_file.name} not found")
    if downscale < 1:
        raise DatasetError(f"downscale={downscale}: expected an integer >= 1")
    poses_bounds = np.load(poses_file)
    if poses_bounds.ndim != 2 or poses_bounds.shape[1] != 17:
        raise DatasetError(f"{poses_file}: shape {poses_bounds.shape}, expected (K, 17)")
    if not np.isfinite(poses_bounds).all():
        bad = int(np.flatnonzero(~np.isfinite(poses_bounds).all(axis=1))[0])
        raise DatasetError(f"{poses_file}: row {bad} holds a NaN or infinite value")
    image_folder_path, resize = image_folder(folder, downscale)
    paths = sorted(p for p in image_folder_path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise FileNotFoundError(f"LLFF folder {image_folder_path}: no images")
    if len(paths) != len(poses_bounds):
        raise DatasetError(f"{poses_file} has {len(poses_bounds)} poses but {image_folder_path} has {len(paths)} images")
    T_world_cam, bounds, T_map_scaled, scale = normalize_llff_poses(poses_bounds)
    positions = _split_positions(len(paths), split, holdout_every)
    images = stack_same_size([read_rgb(paths[i], resize) for i in positions], [paths[i] for i in positions])
    height, width = images.shape[1:3]
    full_height, full_width, full_focal = poses_bounds[0, 4], poses_bounds[0, 9], poses_bounds[0, 14]
    focal = full_focal * width / full_width
    if abs(height / width - full_height / full_width) > 0.02:
        raise DatasetError(f"{image_folder_path}: images {width}x{height} do not match the aspect of the poses' {full_width:.0f}x{full_height:.0f}")
    # hwf says nothing of the principal point: LLFF (and COLMAP's default) put it at the image centre.
    intrinsics = PinholeIntrinsics.centred(focal, focal, width, height)
    normalization = forward_facing_normalization(T_map_scaled, scale, bounds)
    logger.info("LLFF %s: %d images %dx%d, scale %.4f", folder, len(positions), width, height, scale)
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=torch.from_numpy(T_world_cam[positions]),
        intrinsics=intrinsics,
        near=normalization.near,
        far=normalization.far,
        normalization=normalization,
        names=[paths[i].stem for i in positions],
        scene_bounds=NDC_CUBE.clone(),
        source=str(folder),
        indices=positions,
    )


def _split_positions(count: int, split: str, holdout_every: int) -> list[int]:
    held_out = list(range(0, count, holdout_every))
    if split == "all":
        return list(range(count))
    if split == "test":
        return held_out
    if split == "train":
        return [i for i in range(count) if i not in held_out]
    raise DatasetError(f"split {split!r}: expected all, train or test for an LLFF capture")
