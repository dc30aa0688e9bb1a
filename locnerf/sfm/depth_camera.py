"""The depth camera of an RGB-D capture posed by structure from motion, from the SfM points and the depth images.

Structure from motion poses the colour camera; the depth images are the depth camera's, a few centimetres and
about a degree away on a Kinect. Every posed image's SfM points, expressed in its colour camera's frame and in
metres, lie on the surface its depth image sees once moved into the depth camera's frame by the colour camera's
pose there, ``T_depth_colour`` (OpenGL camera axes, the transform ``map build`` records for data posed at the
depth camera). :func:`calibrate_depth_camera` finds it by projective point-to-plane alignment (iteratively
reweighted Gauss-Newton, Cauchy weights): each point is projected into its depth image, matched to the surface
point of that pixel and its normal, and the residual is their distance along the normal. The scale is fixed
beforehand (:mod:`locnerf.sfm.metric`); a depth-to-SfM ratio barely depends on a few centimetres of offset.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.colour_camera import METADATA_KEY, calibrate_colour_camera
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import read_depth
from locnerf.errors import DatasetError
from locnerf.geometry import make_pose, pose_inverse, rotation_angle, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sfm.capture import Capture

logger = logging.getLogger(__name__)

METADATA_RECORD = "depth_camera_calibration"
"""Entry of a map's metadata recording the calibration (method, residuals, points)."""


class DepthCameraConfig(BaseModel):
    """How the depth camera is found from the SfM points."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    iterations: int = Field(30, ge=1, description="Gauss-Newton iterations (each re-matches points to depth pixels).")
    cauchy_scale_m: float = Field(0.01, gt=0, description="Cauchy loss scale of the point-to-plane residuals (metres).")
    max_residual_m: float = Field(0.1, gt=0, description="Residuals beyond this are not matches (metres).")
    max_depth_jump: float = Field(0.05, gt=0, description="A pixel whose neighbours' depths differ by more than this fraction has no normal (an edge).")
    min_points: int = Field(200, ge=6, description="Fewest matched points for a calibration.")
    max_step_deg: float = Field(5.0, gt=0, description="Largest rotation of one iteration (degrees; a larger step is scaled down).")
    max_views: int = Field(60, ge=1, description="Most images used (evenly spread over the capture).")
    depth_stride: int = Field(2, ge=1, description="Every n-th depth pixel is read.")


@dataclass(frozen=True)
class DepthView:
    """One image's SfM points and its depth image.

    Attributes:
        points: (P, 3) float64 points in the colour camera's frame, OpenGL axes, metres.
        depth: (H, W) float32 metres along the depth camera's optical axis, 0 where there is no reading.
        intrinsics: the depth image's camera (its size).
    """

    points: torch.Tensor
    depth: torch.Tensor
    intrinsics: PinholeIntrinsics


@dataclass(frozen=True)
class DepthCameraCalibration:
    """``T_depth_colour`` (4, 4) float64 and the fit's figures (median absolute residual of the matched points, metres)."""

    T_depth_colour: torch.Tensor
    residual_before_m: float
    residual_after_m: float
    points: int
    views: int

    def record(self) -> dict:
        """JSON-ready metadata entry."""
        return {
            "method": "SfM points against the depth images (projective point-to-plane, Cauchy)",
            "residual_before_m": round(self.residual_before_m, 5),
            "residual_after_m": round(self.residual_after_m, 5),
            "points": self.points,
            "views": self.views,
            "translation_m": float(self.T_depth_colour[:3, 3].norm()),
            "rotation_deg": math.degrees(float(rotation_angle(self.T_depth_colour[:3, :3]))),
        }


@dataclass(frozen=True)
class _Surface:
    """A depth image's surface points (H, W, 3) and unit normals (H, W, 3), depth-camera frame, OpenGL axes; ``valid`` (H, W)."""

    points: torch.Tensor
    normals: torch.Tensor
    valid: torch.Tensor
    intrinsics: PinholeIntrinsics


def _surface(depth: torch.Tensor, intrinsics: PinholeIntrinsics, max_jump: float) -> _Surface:
    z = depth.double()
    v, u = torch.meshgrid(torch.arange(z.shape[0], dtype=torch.float64), torch.arange(z.shape[1], dtype=torch.float64), indexing="ij")
    points = torch.stack(((u - intrinsics.cx) / intrinsics.fx * z, -(v - intrinsics.cy) / intrinsics.fy * z, -z), dim=-1)
    normals = torch.zeros_like(points)
    across = points[1:-1, 2:] - points[1:-1, :-2]
    down = points[2:, 1:-1] - points[:-2, 1:-1]
    normals[1:-1, 1:-1] = torch.nn.functional.normalize(torch.linalg.cross(across, down), dim=-1)
    valid = torch.zeros_like(z, dtype=torch.bool)
    centre = z[1:-1, 1:-1]
    smooth = centre > 0
    for neighbour in (z[1:-1, 2:], z[1:-1, :-2], z[2:, 1:-1], z[:-2, 1:-1]):
        smooth &= (neighbour > 0) & ((neighbour - centre).abs() <= max_jump * centre)
    valid[1:-1, 1:-1] = smooth
    return _Surface(points, normals, valid, intrinsics)


def _matches(surface: _Surface, points: torch.Tensor, max_residual: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """For points (P, 3) in the depth frame: (kept mask (P,), surface points (K, 3), normals (K, 3)) at their nearest pixels."""
    z = -points[:, 2]
    camera = surface.intrinsics
    with torch.no_grad():
        u = torch.round(camera.fx * points[:, 0] / z + camera.cx)
        v = torch.round(-camera.fy * points[:, 1] / z + camera.cy)
    inside = (z > 0) & (u >= 0) & (v >= 0) & (u < camera.width) & (v < camera.height)
    u, v = u[inside].long(), v[inside].long()
    keep = inside.clone()
    keep[inside] = surface.valid[v, u]
    u, v = u[surface.valid[v, u]], v[surface.valid[v, u]]
    targets, normals = surface.points[v, u], surface.normals[v, u]
    close = ((points[keep] - targets) * normals).sum(-1).abs() <= max_residual
    keep[keep.clone()] = close
    return keep, targets[close], normals[close]


def _residuals(surfaces: list[_Surface], points: list[torch.Tensor], T: torch.Tensor, max_residual: float):
    """Point-to-plane residuals (N,), moved points (N, 3) and normals (N, 3) of every view under ``T_depth_colour`` ``T``."""
    residuals, moved_all, normals_all = [], [], []
    for surface, local in zip(surfaces, points):
        moved = local @ T[:3, :3].T + T[:3, 3]
        keep, targets, normals = _matches(surface, moved, max_residual)
        residuals.append(((moved[keep] - targets) * normals).sum(-1))
        moved_all.append(moved[keep])
        normals_all.append(normals)
    return torch.cat(residuals), torch.cat(moved_all), torch.cat(normals_all)


def calibrate_depth_camera(views: list[DepthView], config: DepthCameraConfig = DepthCameraConfig()) -> DepthCameraCalibration:
    """``T_depth_colour`` from the SfM points of posed images and their depth images (module docstring).

    Raises:
        DatasetError: fewer than ``config.min_points`` points meet a depth reading (no usable depth, or points
            nowhere near the depth images' surfaces: a scale or a capture gone wrong).
    """
    surfaces = [_surface(view.depth, view.intrinsics, config.max_depth_jump) for view in views]
    points = [view.points.double() for view in views]
    T = torch.eye(4, dtype=torch.float64)
    before = None
    for _ in range(config.iterations):
        residual, moved, normals = _residuals(surfaces, points, T, config.max_residual_m)
        if len(residual) < config.min_points:
            raise DatasetError(
                f"depth camera: {len(residual)} of the SfM points meet a depth reading within {config.max_residual_m} m, expected at least {config.min_points}"
            )
        if before is None:
            before = float(residual.abs().median())
        weights = 1.0 / (1.0 + (residual / config.cauchy_scale_m) ** 2)
        jacobian = torch.cat((torch.linalg.cross(moved, normals), normals), dim=-1)
        hessian = jacobian.T @ (weights[:, None] * jacobian) + 1e-9 * torch.eye(6, dtype=torch.float64)
        step = -torch.linalg.solve(hessian, jacobian.T @ (weights * residual))
        angle = float(step[:3].norm())
        if angle > math.radians(config.max_step_deg):
            step = step * math.radians(config.max_step_deg) / angle
        T = make_pose(so3_exp(step[:3]), step[3:]) @ T
        if float(step.norm()) < 1e-7:
            break
    residual, _, _ = _residuals(surfaces, points, T, config.max_residual_m)
    calibration = DepthCameraCalibration(T, before, float(residual.abs().median()), len(residual), len(views))
    logger.info(
        "depth camera: %.1f mm, %.2f deg from the colour camera; median point-to-plane residual %.1f -> %.1f mm over %d points of %d views",
        1e3 * float(T[:3, 3].norm()),
        math.degrees(float(rotation_angle(T[:3, :3]))),
        1e3 * calibration.residual_before_m,
        1e3 * calibration.residual_after_m,
        calibration.points,
        calibration.views,
    )
    return calibration


def capture_depth_views(reconstruction, capture: Capture, scale: float, config: DepthCameraConfig = DepthCameraConfig()) -> list[DepthView]:
    """The posed images' SfM points in their colour camera's frame (metres, OpenGL axes) beside their depth images.

    Args:
        reconstruction: pycolmap.Reconstruction of ``capture``.
        scale: metres per SfM unit.
    """
    if capture.depth_paths is None or capture.depth_camera is None:
        return []
    depth_of = dict(zip(capture.names, capture.depth_paths))
    posed = [image for image in reconstruction.images.values() if image.has_pose and image.name in depth_of]
    posed.sort(key=lambda image: capture.names.index(image.name))
    chosen = [posed[round(i)] for i in torch.linspace(0, len(posed) - 1, min(config.max_views, len(posed))).tolist()] if posed else []
    views = []
    for image in chosen:
        world = torch.from_numpy(np.array([reconstruction.points3D[p.point3D_id].xyz for p in image.points2D if p.has_point3D()], dtype=np.float64)).reshape(
            -1, 3
        )
        pose = torch.from_numpy(image.cam_from_world().matrix())
        local = (world @ pose[:, :3].T + pose[:, 3]) * scale * torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64)  # OpenCV -> OpenGL axes
        depth = torch.from_numpy(read_depth(depth_of[image.name], config.depth_stride))
        camera = capture.depth_camera.decimated(round(capture.depth_camera.width / depth.shape[1]))
        views.append(DepthView(local, depth, camera))
    return views


def with_calibrated_depth_camera(images: PosedImages, views: list[DepthView], config: DepthCameraConfig = DepthCameraConfig()) -> tuple[PosedImages, dict]:
    """``images`` (posed at the SfM colour camera, metric) with their depth camera placed by :func:`calibrate_depth_camera`,
    and the map metadata recording it (``T_depth_colour``, read back wherever the map meets a data set, and the fit's figures).
    Without depth images, or when the points meet too few depth readings (a warning), the depth camera stays at the colour camera."""
    if images.depths is None or not views:
        return images, {}
    try:
        calibration = calibrate_depth_camera(views, config)
    except DatasetError as error:
        logger.warning("depth camera taken at the colour camera's pose: %s", error)
        return images, {METADATA_RECORD: {"skipped": str(error)}}
    T_cam_depth = pose_inverse(calibration.T_depth_colour)
    return replace(images, T_cam_depth=T_cam_depth), {METADATA_KEY: calibration.T_depth_colour.tolist(), METADATA_RECORD: calibration.record()}


def with_photometric_depth_camera(images: PosedImages) -> tuple[PosedImages, dict]:
    """``images`` (posed at the SfM colour camera, metric, with depth) with their depth camera placed by the photometric
    calibration of posed RGB-D data (:func:`locnerf.data.colour_camera.calibrate_colour_camera`) run on the colour
    poses taken as the depth camera's: depth points placed from each pose, and the offset that makes their grey values
    agree across the colour images that see them; the depth camera then sits at its inverse. One pass from the colour
    camera: on the kitchen's SfM build it landed 11.7 mm and 0.57° from the calibration on the data set's depth-camera
    poses, where the depth camera at the colour camera is 29 mm and 1.15° from it (docs/MAPS.md). Without depth images, or with too few
    overlapping frames (a warning), the depth camera stays at the colour camera."""
    if images.depths is None:
        return images, {}
    started = time.monotonic()
    try:
        calibration = calibrate_colour_camera(replace(images, T_cam_depth=None))
    except DatasetError as error:
        logger.warning("depth camera taken at the colour camera's pose: %s", error)
        return images, {METADATA_RECORD: {"skipped": str(error)}}
    record = {
        "method": "photometric",
        "translation_m": float(calibration.T_depth_colour[:3, 3].norm()),
        "rotation_deg": math.degrees(float(rotation_angle(calibration.T_depth_colour[:3, :3]))),
        **calibration.record(time.monotonic() - started),
    }
    return replace(images, T_cam_depth=pose_inverse(calibration.T_depth_colour)), {METADATA_KEY: calibration.T_depth_colour.tolist(), METADATA_RECORD: record}
