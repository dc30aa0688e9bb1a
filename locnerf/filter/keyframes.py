"""Place recognition against the map: which known views look most like an image.

A :class:`KeyframeIndex` holds keyframe poses (the camera poses the map was built from, or any
plausible poses) and a thumbnail of the map's rendering at each. An image is compared with every
thumbnail by normalised cross-correlation; the best-matching keyframes are where a lost robot
probably is. Kidnapping recovery draws part of its fresh particles around them
(:mod:`locnerf.filter.recovery`), so a robot carried to the far side of the map is found by
appearance instead of by the luck of uniform draws.

Thumbnails are ``width`` pixels wide (the height keeps the camera's aspect). The map's views are
rendered (by the caller: the filter reaches rendering only through the measurement model) at
``supersample`` times that resolution and area-averaged, as the query image is, so both sides are
low-passed alike; :func:`locnerf.maps.keyframes.build_keyframe_index` does both.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics


def thumbnail_shape(intrinsics: PinholeIntrinsics, width: int) -> tuple[int, int]:
    """(height, width) of a thumbnail ``width`` pixels wide with the camera's aspect ratio."""
    return max(1, round(width * intrinsics.height / intrinsics.width)), width


def thumbnail_descriptors(images: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Images (N, H, W, 3) -> (N, h·w·3) float64 descriptors: area-averaged to ``shape`` (h, w),
    then zero mean and unit norm per image (so brightness offsets and contrast do not count)."""
    pooled = F.adaptive_avg_pool2d(images.permute(0, 3, 1, 2).double(), shape)
    flat = pooled.reshape(len(images), -1)
    flat = flat - flat.mean(dim=1, keepdim=True)
    return flat / torch.linalg.vector_norm(flat, dim=1, keepdim=True).clamp_min(1e-12)


@dataclass(frozen=True)
class KeyframeIndex:
    """Keyframe poses and thumbnails of the map seen from them.

    Attributes:
        poses: (K, 4, 4) float64 camera-to-world keyframe poses (map frame), CPU.
        descriptors: (K, D) float64 thumbnail descriptors (:func:`thumbnail_descriptors`).
        shape: (h, w) of the thumbnails.
        camera: the camera the thumbnails were rendered for (before the thumbnail scaling).
        spacing: median distance (map units) from a keyframe to its nearest other keyframe: how
            far a robot may be from the keyframe that looks most like its view.
    """

    poses: torch.Tensor
    descriptors: torch.Tensor
    shape: tuple[int, int]
    camera: PinholeIntrinsics
    spacing: float

    def __len__(self) -> int:
        return self.poses.shape[0]

    def matches(self, intrinsics: PinholeIntrinsics, tolerance: float = 0.01) -> bool:
        """Whether images of ``intrinsics`` look like the thumbnails' camera: focal lengths and
        principal point relative to the image size agree within ``tolerance`` (the size may differ)."""
        mine, theirs = _relative_intrinsics(self.camera), _relative_intrinsics(intrinsics)
        return all(abs(a - b) <= tolerance * abs(a) for a, b in zip(mine, theirs))

    def query(self, image: torch.Tensor, count: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``count`` keyframes most like ``image`` (H, W, 3) in [0, 1].

        Returns:
            poses (C, 4, 4) float64 best first, and their correlation scores (C,) in [-1, 1];
            C = min(count, K).
        """
        if image.ndim != 3 or image.shape[-1] != 3:
            raise ValueError(f"query image: expected shape (H, W, 3), got {tuple(image.shape)}")
        if count < 1:
            raise ValueError(f"keyframe count {count}: expected >= 1")
        scores = self.descriptors @ thumbnail_descriptors(image[None].cpu(), self.shape)[0]
        best = torch.topk(scores, min(count, len(self))).indices
        return self.poses[best], scores[best]


def _relative_intrinsics(intrinsics: PinholeIntrinsics) -> tuple[float, float, float, float]:
    """Focal lengths and principal point as fractions of the image's extent: unchanged by resizing
    (the principal point measured from the image's edge, ``cx + 0.5``; see :meth:`PinholeIntrinsics.scaled`)."""
    return (
        intrinsics.fx / intrinsics.width,
        intrinsics.fy / intrinsics.height,
        (intrinsics.cx + 0.5) / intrinsics.width,
        (intrinsics.cy + 0.5) / intrinsics.height,
    )


def nearest_neighbour_spacing(positions: torch.Tensor) -> float:
    """Median distance from each of the positions (K, 3) to its nearest other one (0 for K < 2)."""
    if positions.shape[0] < 2:
        return 0.0
    distances = torch.cdist(positions.double(), positions.double())
    distances.fill_diagonal_(float("inf"))
    return float(distances.min(dim=1).values.median())


def thumbnail_camera(intrinsics: PinholeIntrinsics, width: int, supersample: int) -> PinholeIntrinsics:
    """The camera to render keyframe views with: ``intrinsics`` scaled to ``width · supersample`` pixels wide."""
    if width < 2 or supersample < 1:
        raise ValueError(f"thumbnail width {width}, supersample {supersample}: expected width >= 2 and supersample >= 1")
    return intrinsics.scaled(width * supersample / intrinsics.width)


def index_from_views(poses: torch.Tensor, views: torch.Tensor, intrinsics: PinholeIntrinsics, width: int) -> KeyframeIndex:
    """A keyframe index from the map's views (K, H, W, 3) rendered at ``poses`` (K, 4, 4) with
    (a scaled copy of) ``intrinsics``, the camera whose images will be queried."""
    validate_poses(poses, name="keyframe poses")
    if poses.ndim != 3 or poses.shape[0] == 0 or views.shape[0] != poses.shape[0]:
        raise ValueError(f"keyframe poses {tuple(poses.shape)} and views {tuple(views.shape)}: expected (K>=1, 4, 4) and (K, H, W, 3)")
    shape = thumbnail_shape(intrinsics, width)
    positions = poses[:, :3, 3].double().cpu()
    return KeyframeIndex(poses.double().cpu(), thumbnail_descriptors(views.cpu(), shape), shape, intrinsics, nearest_neighbour_spacing(positions))
