"""Reading image files into float RGB arrays, with optional downscaling and background compositing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from locnerf.errors import DatasetError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".JPG", ".PNG", ".JPEG")


def resolve_image_path(path: Path) -> Path:
    """``path`` itself, or ``path`` with an image suffix appended when the file names none.

    Raises:
        FileNotFoundError: naming the path when no such image exists.
    """
    if path.is_file():
        return path
    for suffix in IMAGE_SUFFIXES:
        candidate = path.with_name(path.name + suffix)
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"image {path}: no such file (also tried the suffixes {', '.join(IMAGE_SUFFIXES)})")


def read_rgb(path: Path, downscale: float = 1.0, background: tuple[float, float, float] | None = None) -> np.ndarray:
    """One image as (H, W, 3) float32 RGB in [0, 1].

    Args:
        path: image file (PNG/JPEG; 8- or 16-bit; gray, RGB or RGBA).
        downscale: integer-like factor >= 1; area-averaged resize (as nerf-pytorch's ``half_res``).
        background: RGB to composite RGBA images on; ``None`` drops the alpha channel.
    Raises:
        DatasetError: when the file cannot be decoded.
    """
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DatasetError(f"image {path}: cannot be decoded as an image")
    scale = 65535.0 if raw.dtype == np.uint16 else 255.0
    image = raw.astype(np.float32) / scale
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    channels = image.shape[2]
    image = image[:, :, [2, 1, 0, 3]] if channels == 4 else image[:, :, [2, 1, 0]]
    if downscale != 1.0:
        height, width = image.shape[:2]
        size = (max(1, round(width / downscale)), max(1, round(height / downscale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    if channels == 4:
        alpha = image[:, :, 3:4]
        rgb = image[:, :, :3]
        image = rgb * alpha + np.asarray(background, np.float32) * (1.0 - alpha) if background is not None else rgb
    return np.ascontiguousarray(image, dtype=np.float32)


def stack_same_size(images: list[np.ndarray], paths: list[Path]) -> np.ndarray:
    """(K, H, W, 3) from images that must all share one size.

    Raises:
        DatasetError: naming the first image whose size differs from the first one's.
    """
    if not images:
        raise DatasetError("no images to stack")
    first = images[0].shape
    for image, path in zip(images, paths):
        if image.shape != first:
            raise DatasetError(f"image {path} has size {image.shape[1]}x{image.shape[0]}: expected {first[1]}x{first[0]} like {paths[0]}")
    return np.stack(images)
