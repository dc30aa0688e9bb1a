"""The colour camera of an RGB-D sequence whose colour and depth images are not registered (7-Scenes).

7-Scenes poses the Kinect's *depth* camera; its colour camera sits a few centimetres away (redkitchen:
about 3 cm along x, 1.6 cm along y and 0.8° about x, calibrated below). Rays of colour pixels cast from the
depth camera's pose paint every surface from a slightly wrong place, and by a different amount in
every view, so a map built that way blurs and its likelihood peaks centimetres off.

:func:`calibrate_colour_camera` estimates ``T_depth_colour``, the colour camera's pose in the depth
camera's frame (OpenGL axes, map units), from the sequence itself: depth pixels of reference frames
become world points (depth camera pose, depth intrinsics); each point is projected into the colour
images of its reference frame and of neighbouring frames (``T_world_depth · T_depth_colour``, colour
intrinsics) where the depth image of that frame sees it (a depth test against that frame's reading);
the offset that makes the grey values of every point agree across its views is the colour camera:
Adam on a rotation vector and a translation, minimising a robust (Cauchy) loss of each view's grey
value against the point's mean, on slightly blurred images, after each view's exposure gain. The colour intrinsics stay as
given: their focal length trades against the offset along the optical axis.

:func:`with_colour_camera` moves a sequence's poses onto the colour camera and keeps the depth
camera as ``PosedImages.T_cam_depth``. A map built from such a sequence records ``T_depth_colour`` in
its metadata (:data:`METADATA_KEY`), and whatever reads a data set to use with that map applies
the same offset (:func:`colour_camera_of`): its ground truth is then the colour camera's.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from typing import Annotated

import cv2
import numpy as np
import torch
from pydantic import AfterValidator, Field

from locnerf.data.depth_visibility import project_world_points, seen_in_depth
from locnerf.data.detect import read_dataset
from locnerf.data.map_lens import on_map_lens
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import depth_points
from locnerf.data.sfm_poses import POSES_METADATA_KEY, check_pose_source
from locnerf.errors import DatasetError
from locnerf.filter.warp import sample_image
from locnerf.geometry.se3 import make_pose, pose_inverse
from locnerf.geometry.so3 import so3_exp
from locnerf.geometry.validation import InvalidPoseError, validate_pose_setting
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

METADATA_KEY = "T_depth_colour"
"""Map metadata key of the colour camera's pose in the depth camera's frame (4×4 nested list, map units)."""
RIGID_TOLERANCE = 1e-6


@dataclass(frozen=True)
class CalibrationConfig:
    """How :func:`calibrate_colour_camera` samples the sequence and optimises.

    Attributes:
        references: reference frames, evenly spread over the sequence.
        points: depth points drawn per reference frame.
        neighbours: frame offsets (in sequence order) whose colour images also see a reference's points.
        iterations: Adam steps.
        learning_rate: Adam step size (radians and map units).
        blur: Gaussian blur of the grey images, pixels (standard deviation).
        depth_tolerance: a point is visible in a frame where its depth is within this fraction of the frame's reading.
        min_views: views a point needs to count.
        seed: seed of the point draws.
    """

    references: int = 60
    points: int = 1500
    neighbours: tuple[int, ...] = (-24, -12, 12, 24)
    iterations: int = 150
    learning_rate: float = 3e-3
    depth_tolerance: float = 0.04
    blur: float = 1.0
    min_views: int = 3
    seed: int = 0


@dataclass(frozen=True)
class ColourCalibration:
    """The result of :func:`calibrate_colour_camera`.

    Attributes:
        T_depth_colour: (4, 4) float64, the colour camera's pose in the depth camera's frame (OpenGL axes, map units).
        inconsistency_before: the mean robust loss of the points' grey values against their means
            (:func:`_inconsistency`), with no offset.
        inconsistency_after: the same with ``T_depth_colour``.
        points: views of points that counted (each point seen in at least ``min_views`` views).
    """

    T_depth_colour: torch.Tensor
    inconsistency_before: float
    inconsistency_after: float
    points: int

    def record(self, seconds: float) -> dict:
        """Its figures for a map's metadata, with the ``seconds`` it took."""
        return {
            "inconsistency_before": round(self.inconsistency_before, 5),
            "inconsistency_after": round(self.inconsistency_after, 5),
            "points": self.points,
            "seconds": round(seconds, 1),
        }


def _grey(images: torch.Tensor, blur: float) -> torch.Tensor:
    """(K, H, W) luma of (K, H, W, 3) RGB in [0, 1] (ITU-R BT.601 weights), Gaussian-blurred by ``blur`` pixels
    (bilinear reads of a band-limited image vary smoothly with the offset)."""
    grey = images.double() @ torch.tensor([0.299, 0.587, 0.114], dtype=torch.float64)
    if blur > 0:
        grey = torch.from_numpy(np.stack([cv2.GaussianBlur(frame, (0, 0), blur) for frame in grey.numpy()]))
    return grey


def _reference_points(images: PosedImages, config: CalibrationConfig) -> list[tuple[int, torch.Tensor]]:
    """(frame, (P, 4) float64 homogeneous world points) of randomly drawn valid depth pixels of evenly spread reference frames."""
    assert images.depths is not None and images.depth_intrinsics is not None
    generator = torch.Generator().manual_seed(config.seed)
    count = len(images)
    frames = torch.linspace(0, count - 1, min(config.references, count)).round().long().unique().tolist()
    references = []
    for frame in frames:
        points = depth_points(images.depths[frame : frame + 1], images.T_world_cam[frame : frame + 1], images.depth_intrinsics)
        if len(points):
            chosen = points[torch.randperm(len(points), generator=generator)[: config.points]]
            references.append((frame, torch.cat((chosen, torch.ones_like(chosen[:, :1])), dim=-1)))
    return references


class _Views:
    """For every reference's points, the frames that see them (by the depth test, independent of the offset)."""

    def __init__(self, images: PosedImages, references: list[tuple[int, torch.Tensor]], config: CalibrationConfig) -> None:
        self.entries: list[tuple[torch.Tensor, list[int], torch.Tensor]] = []
        for frame, points in references:
            frames = [frame + offset for offset in (0, *config.neighbours) if 0 <= frame + offset < len(images)]
            visible = torch.stack([seen_in_depth(images, j, points, config.depth_tolerance) for j in frames])
            keep = visible.sum(0) >= config.min_views
            if keep.any():
                self.entries.append((points[keep], frames, visible[:, keep]))


def _residuals(
    views: _Views, grey: torch.Tensor, T_world_depth: torch.Tensor, T_depth_colour: torch.Tensor, camera: PinholeIntrinsics, min_views: int
) -> torch.Tensor:
    """(S,) differences between each view's grey value of a point and the point's mean over its views, for
    every view of every point seen in at least ``min_views`` views.

    ``grey`` (K, H, W, 1); ``T_world_depth`` (K, 4, 4): each frame's depth camera; ``T_depth_colour`` (4, 4): the colour camera in it.
    """
    residuals = []
    for points, frames, visible in views.entries:
        values, masks = [], []
        for row, frame in enumerate(frames):
            pixels, _, inside = project_world_points(points, T_world_depth[frame] @ T_depth_colour, camera)
            mask = visible[row] & inside
            masks.append(mask)
            values.append(sample_image(grey[frame], pixels[None], mask[None])[0, :, 0])
        value, mask = torch.stack(values), torch.stack(masks)
        mask = mask & (mask.sum(0) >= min_views)
        views_per_point = mask.sum(0).clamp(min=1)
        mean = (value * mask).sum(0) / views_per_point
        with torch.no_grad():  # each view's exposure: the median ratio of its values to the points' means
            ratio = torch.where(mask, value / mean.clamp(min=1e-3), torch.nan)
            gain = torch.nanmedian(ratio, dim=1).values.nan_to_num(1.0).clamp(0.5, 2.0)
        value = value / gain[:, None]
        mean = (value * mask).sum(0) / views_per_point
        residuals.append((value - mean)[mask])
    return torch.cat(residuals) if residuals else grey.new_zeros(0)


def _inconsistency(residuals: torch.Tensor, scale: float) -> torch.Tensor:
    """Mean Cauchy loss ``log(1 + (r / scale)²)`` of the residuals: occlusions the depth test missed,
    reflections and sensor noise count little, so they cannot pull the offset along a direction the
    images barely tell apart (a turn about a point at the scene's depth against a sideways shift)."""
    return torch.log1p((residuals / scale) ** 2).mean()


def calibrate_colour_camera(images: PosedImages, config: CalibrationConfig | None = None) -> ColourCalibration:
    """Estimate the colour camera's pose in the depth camera's frame from a posed RGB-D sequence.

    Args:
        images: frames in capture order, ``T_world_cam`` the depth camera's poses, with depth images.
        config: sampling and optimisation settings.
    Returns:
        the calibration (``T_depth_colour`` (4, 4) float64 and the photometric inconsistency before and after).
    Raises:
        DatasetError: without depth images, or when no depth point is seen in enough views.
    """
    config = config or CalibrationConfig()
    if images.depths is None or images.depth_intrinsics is None:
        raise DatasetError(f"{images.source}: calibrating the colour camera needs depth images")
    if images.T_cam_depth is not None:
        raise DatasetError(f"{images.source}: the poses are already the colour camera's (T_cam_depth is set)")
    views = _Views(images, _reference_points(images, config), config)
    if not views.entries:
        raise DatasetError(f"{images.source}: no depth point is seen in {config.min_views} frames; cannot calibrate the colour camera")
    grey = _grey(images.images, config.blur)[..., None]
    T_world_depth = images.T_world_cam.double()
    rotation = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    translation = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([rotation, translation], lr=config.learning_rate)
    with torch.no_grad():
        start = _residuals(views, grey, T_world_depth, torch.eye(4, dtype=torch.float64), images.intrinsics, config.min_views)
        scale = max(float(1.4826 * start.abs().median()), 1e-6)  # the residuals' robust spread with no offset
        before = _inconsistency(start, scale)
    for _ in range(config.iterations):
        T_depth_colour = make_pose(so3_exp(rotation), translation)
        residuals = _residuals(views, grey, T_world_depth, T_depth_colour, images.intrinsics, config.min_views)
        loss = _inconsistency(residuals, scale)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        T_depth_colour = make_pose(so3_exp(rotation), translation)
        after = _inconsistency(_residuals(views, grey, T_world_depth, T_depth_colour, images.intrinsics, config.min_views), scale)
    counted = len(start)
    angle = math.degrees(float(rotation.detach().norm()))
    logger.info(
        "colour camera in the depth camera's frame: translation %s map units, rotation %.2f deg; inconsistency %.4f -> %.4f over %d point views",
        [round(x, 4) for x in translation.detach().tolist()],
        angle,
        float(before),
        float(after),
        counted,
    )
    return ColourCalibration(T_depth_colour.detach(), float(before), float(after), counted)


def with_colour_camera(images: PosedImages, T_depth_colour: torch.Tensor) -> PosedImages:
    """``images`` posed at their colour camera: ``T_world_cam · T_depth_colour``, the depth camera kept as ``T_cam_depth``.

    Raises:
        DatasetError: if the poses are already the colour camera's.
    """
    if images.T_cam_depth is not None:
        raise DatasetError(f"{images.source}: the poses are already the colour camera's (T_cam_depth is set)")
    offset = T_depth_colour.to(torch.float64)
    return replace(images, T_world_cam=images.T_world_cam.double() @ offset, T_cam_depth=pose_inverse(offset))


def colour_camera_of(metadata: dict) -> torch.Tensor | None:
    """The map's ``T_depth_colour`` (4, 4) float64 from its metadata; None for a map of registered cameras.

    Raises:
        DatasetError: if the entry is not a rigid 4×4 transform.
    """
    value = metadata.get(METADATA_KEY)
    return None if value is None else colour_camera_matrix(value)


def colour_camera_matrix(value: object) -> torch.Tensor:
    """``T_depth_colour`` as a (4, 4) float64 tensor from a 4×4 nested list.

    Raises:
        DatasetError: if it is not a rigid 4×4 transform (orthonormal rotation, determinant +1, last row 0 0 0 1).
    """
    try:
        validate_pose_setting(value, METADATA_KEY, atol=RIGID_TOLERANCE)
    except InvalidPoseError as error:
        raise DatasetError(str(error)) from None
    return torch.tensor(value, dtype=torch.float64)


def _checked_setting(value: list[list[float]] | None) -> list[list[float]] | None:
    if value is not None:
        colour_camera_matrix(value)
    return value


ColourCameraSetting = Annotated[
    list[list[float]] | None,
    AfterValidator(_checked_setting),
    Field(
        None,
        description="T_depth_colour of the map (its metadata, `locnerf map info`): the colour camera's pose in the depth camera's frame,"
        " map units, for data posed at the depth camera (7-Scenes); the replayed poses and depth follow it. None: as the data set poses them.",
    ),
]
"""A source setting naming the colour camera a map was built for (services' replay and scenario sources)."""


def map_colour_camera(radiance_map: object) -> torch.Tensor | None:
    """The ``T_depth_colour`` a map records (:func:`colour_camera_of`); None for maps without one or without metadata (the procedural world)."""
    return colour_camera_of(getattr(radiance_map, "metadata", None) or {})


def on_map_camera(images: PosedImages, radiance_map: object) -> PosedImages:
    """``images`` on the colour camera ``radiance_map`` was built for: moved by the ``T_depth_colour``
    its metadata records (maps built from RGB-D data posed at the depth camera), else as they are.

    Raises:
        DatasetError: if the map's entry is not a rigid 4×4 transform.
    """
    T_depth_colour = map_colour_camera(radiance_map)
    if T_depth_colour is None or images.T_cam_depth is not None:
        return images
    return with_colour_camera(images, T_depth_colour)


def metric_offset(frames: PosedImages) -> torch.Tensor | None:
    """``frames.T_cam_depth`` with its translation in metres (None when the depth camera sits at the colour camera's pose)."""
    if frames.T_cam_depth is None:
        return None
    offset = frames.T_cam_depth.double().clone()
    offset[:3, 3] /= frames.normalization.scale
    return offset


def map_pose_source(radiance_map: object) -> str:
    """The pose source (``dslam`` | ``sfm``, :mod:`locnerf.data.sfm_poses`) a map was built from: its metadata's, else ``dslam``."""
    return (getattr(radiance_map, "metadata", None) or {}).get(POSES_METADATA_KEY, "dslam")


def check_map_poses(radiance_map: object, poses: str) -> str:
    """``poses`` if the map was built from that pose source (each ground truth has its own world frame).

    Raises:
        DatasetError: naming both, for an unknown name or one that is not the map's.
    """
    built = map_pose_source(radiance_map)
    if check_pose_source(poses) != built:
        raise DatasetError(f"--poses {poses}: the map was built from {built} poses and lives in that ground truth's world frame; score it with --poses {built}")
    return poses


def read_on_map_camera(data: object, radiance_map: object, poses: str = "dslam", in_map_frame: bool = True, **read: object) -> PosedImages:
    """A data set's frames (:func:`locnerf.data.read_dataset` with ``read``'s arguments) posed by ``poses``,
    on the colour camera ``radiance_map`` was built for (:func:`on_map_camera`; with ``sfm`` the poses
    are the colour camera's already and the map's calibration places the depth camera), in the map's frame
    (:meth:`PosedImages.in_frame`: a map aligned to the data set by ``locnerf map align`` has its own), and
    through the lens an SfM map records onto its camera (:func:`locnerf.data.map_lens.on_map_lens`).
    ``in_map_frame=False`` leaves them in the reader's frame (for what else is given in that frame: logged starts).

    Raises:
        DatasetError: ``poses`` unknown or not the map's (:func:`check_map_poses`), and the reader's errors.
    """
    check_map_poses(radiance_map, poses)
    T_depth_colour = map_colour_camera(radiance_map) if poses == "sfm" else None
    frames = on_map_camera(read_dataset(data, poses=poses, T_depth_colour=T_depth_colour, **read), radiance_map)
    frames = on_map_lens(frames, radiance_map)
    return frames.in_frame(radiance_map.normalization) if in_map_frame else frames


def sfm_training_frames(data: object, split: str, downscale: int | None, stride: int, calibrate: bool = True) -> tuple[PosedImages, dict]:
    """A split posed by the SfM pseudo ground truth (the colour camera's poses), and the map metadata recording it.

    The depth camera's offset from the colour camera is the Kinect's own: :func:`calibrate_colour_camera` on
    the same frames posed by the data set's depth-camera (dSLAM) poses measures it, and the SfM frames place
    their depth camera by its inverse. ``calibrate`` False (or no depth images): depth camera at the colour camera.
    """
    metadata: dict = {POSES_METADATA_KEY: "sfm"}
    T_depth_colour = None
    dslam = read_dataset(data, split=split, downscale=downscale, stride=stride) if calibrate else None
    if dslam is not None and dslam.depths is not None:
        started = time.monotonic()
        try:
            calibration = calibrate_colour_camera(dslam)
        except DatasetError as error:  # too few overlapping frames (a sparse subset), as in map build
            logger.warning("colour camera not calibrated, depth camera taken at the SfM colour camera: %s", error)
            metadata["colour_calibration"] = {"skipped": str(error)}
            return read_dataset(data, split=split, downscale=downscale, stride=stride, poses="sfm"), metadata
        T_depth_colour = calibration.T_depth_colour
        metadata[METADATA_KEY] = T_depth_colour.tolist()
        metadata["colour_calibration"] = {"poses": "dslam", **calibration.record(time.monotonic() - started)}
    return read_dataset(data, split=split, downscale=downscale, stride=stride, poses="sfm", T_depth_colour=T_depth_colour), metadata
