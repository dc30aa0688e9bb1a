"""Depth measurement for RGB-D cameras: a truncated, scale-free likelihood of depth residuals.

An RGB-D camera measures the distance to the scene directly. For M depth pixels q_j of the
observed depth image D (valid readings, drawn uniformly, shared by every particle), the particle
X_i predicts a depth d_ij (the map's surface along the depth camera's ray through q_j, measured
along the optical axis), and is weighted, in the same scale-free family as eq. 5 for colour, by

    log w_i^d = γ_d · (log M − log Σ_j min(r_ij², c²)),   r_ij = d_ij − D(q_j),

with c = ``truncation``: a residual counts at most c, so holes, depth edges, glass and moving
things cannot dominate the sum; a prediction that is missing (the ray met nothing) counts c². The
sum is floored as eq. 5's (:func:`locnerf.filter.measurement.log_likelihood_from_errors`), so a
perfect fit is large and finite. The term multiplies the colour likelihood (their logs add).

Two ways to get d_ij:

- rendered (:func:`rendered_depth_log_likelihoods`): every particle casts its depth-camera rays
  through the M pixels into the map (``render_surface``), as the colour measurement renders.
- warped (:func:`warped_depth_log_likelihoods`): for a converged cloud, M surface points X_j of the
  one reference render (:mod:`locnerf.filter.warp`) are moved into each particle's camera: the
  prediction is their camera-frame depth, the observation the depth image at their projection
  (:func:`read_depth_at`: bilinear on a smooth surface, else the nearest pixel). No rendering per particle.

- surface distance (:func:`surface_distance_log_likelihoods`, ``likelihood = "surface_distance"``): each
  depth pixel's reading becomes a point in the depth camera's frame; placed in the world by each
  particle's depth-camera pose, its residual is its distance to the nearest surface of the map's
  surface-distance layer (:mod:`locnerf.field.surface_distance`, built from the training depth images):
  the likelihood-field model, with no rendering.

The depth camera sits at the particle pose times ``DepthObservation.T_cam_depth`` (its pose in the
colour camera's frame: 7-Scenes' calibrated offset, :mod:`locnerf.data.colour_camera`; at the particle
pose itself when None) with its own intrinsics; depth images are never resampled onto the colour grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from locnerf.filter.measurement import draw_uniformly, log_likelihood_from_errors, pixel_coordinates
from locnerf.filter.measurement_config import DepthConfig
from locnerf.filter.warp import SurfaceRays, points_in_cameras, project_camera_points
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import SurfaceDistanceLookup
from locnerf.render.rays import camera_directions_from_pixels, pixel_grid, rays_from_poses_and_pixels

__all__ = [
    "DepthConfig",
    "DepthObservation",
    "SurfaceDistanceLookup",
    "depth_log_likelihoods",
    "read_depth_at",
    "reading_points",
    "render_depth_image",
    "rendered_depth_log_likelihoods",
    "sample_depth_pixels",
    "surface_distance_log_likelihoods",
    "warped_depth_log_likelihoods",
]

# A ray whose opacity is below this met nothing: its predicted depth is missing.
_MIN_OPACITY = 0.5


@dataclass(frozen=True)
class DepthObservation:
    """One depth image and its camera.

    Attributes:
        depth: (Hd, Wd) float depth along the depth camera's optical axis, map units; 0 = no reading.
        intrinsics: the depth camera (Wd × Hd).
        T_cam_depth: (4, 4) the depth camera's pose in the particle (colour) camera's frame, translation
            in the units of ``depth``; None: the depth camera sits at the particle pose.
    """

    depth: torch.Tensor
    intrinsics: PinholeIntrinsics
    T_cam_depth: torch.Tensor | None = None

    def __post_init__(self) -> None:
        expected = (self.intrinsics.height, self.intrinsics.width)
        if not isinstance(self.depth, torch.Tensor) or self.depth.ndim != 2 or tuple(self.depth.shape) != expected:
            shape = tuple(self.depth.shape) if isinstance(self.depth, torch.Tensor) else type(self.depth).__name__
            raise ValueError(f"DepthObservation.depth of shape {shape}: expected (Hd, Wd) = {expected} for the depth intrinsics")
        if not self.depth.is_floating_point():
            raise ValueError(f"DepthObservation.depth of dtype {self.depth.dtype}: expected floating-point depths in map units")
        if self.T_cam_depth is not None and tuple(self.T_cam_depth.shape) != (4, 4):
            raise ValueError(f"DepthObservation.T_cam_depth of shape {tuple(self.T_cam_depth.shape)}: expected (4, 4)")

    def scaled(self, scale: float) -> DepthObservation:
        """The same observation with depths and the depth camera's offset in units ``scale`` times larger."""
        offset = None
        if self.T_cam_depth is not None:
            offset = self.T_cam_depth.clone()
            offset[:3, 3] *= scale
        return DepthObservation(self.depth * scale, self.intrinsics, offset)

    def depth_poses(self, poses: torch.Tensor) -> torch.Tensor:
        """(N, 4, 4) depth-camera poses of the particle poses (N, 4, 4)."""
        return poses if self.T_cam_depth is None else poses @ self.T_cam_depth.to(poses.device, poses.dtype)

    def valid(self, config: DepthConfig) -> torch.Tensor:
        """(Hd, Wd) bool: finite readings within [min_depth, max_depth]."""
        depth = self.depth
        return torch.isfinite(depth) & (depth >= config.min_depth) & (depth <= config.max_depth)


def render_depth_image(render_surface: SurfaceRays, pose: torch.Tensor, intrinsics: PinholeIntrinsics) -> DepthObservation:
    """The depth image the map predicts from ``pose`` (4, 4) with the camera ``intrinsics``: each pixel's
    expected surface point's depth along the optical axis, 0 (no reading) where the ray met nothing.
    (Benchmarks and tests observe it; the likelihoods above render only the pixels they need.)"""
    origins, directions = rays_from_poses_and_pixels(pose[None], pixel_grid(intrinsics, device=pose.device).to(pose.dtype), intrinsics)
    _, points, opacity = render_surface(origins[0], directions[0])
    depth = -((points - origins[0].to(points)) @ pose[:3, 2].to(points))
    depth = torch.where(opacity >= _MIN_OPACITY, depth, torch.zeros_like(depth))
    return DepthObservation(depth.reshape(intrinsics.height, intrinsics.width).float(), intrinsics)


def sample_depth_pixels(observation: DepthObservation, config: DepthConfig, generator: torch.Generator) -> torch.Tensor:
    """M = ``config.pixels`` pixels of valid readings, drawn uniformly (with replacement only when
    fewer are valid). Returns (M, 2) float32 (u, v) = (column, row) of the depth image.

    Raises:
        ValueError: if the image has no valid reading.
    """
    valid = torch.nonzero(observation.valid(config).cpu().reshape(-1)).reshape(-1)
    if len(valid) == 0:
        raise ValueError(
            f"depth image {observation.intrinsics.width}x{observation.intrinsics.height}: no reading within "
            f"[{config.min_depth}, {config.max_depth}]; expected at least one valid depth pixel"
        )
    return pixel_coordinates(draw_uniformly(valid, config.pixels, generator), observation.intrinsics.width)


def depth_log_likelihoods(poses: torch.Tensor, predicted_depth: torch.Tensor, observed_depth: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """``γ_d (log M − log Σ_j min(r_ij², c²))`` of every particle.

    Args:
        poses: (N, 4, 4) the particles the predictions belong to (for shape and device only).
        predicted_depth: (N, M) depths the map predicts; NaN or ±inf where missing (counts c²).
        observed_depth: (M,) observed depths, or (N, M) one per particle; NaN where missing (counts c²).
    Returns:
        (N,) float64 log-likelihoods; zeros when M = 0 (no depth, no evidence).
    """
    count = predicted_depth.shape[-1]
    if predicted_depth.ndim != 2 or predicted_depth.shape[0] != poses.shape[0]:
        raise ValueError(f"predicted_depth: expected shape ({poses.shape[0]}, M) for {poses.shape[0]} poses, got {tuple(predicted_depth.shape)}")
    if observed_depth.shape[-1] != count:
        raise ValueError(f"observed_depth: expected shape ({count},) to match the predictions, got {tuple(observed_depth.shape)}")
    if count == 0:
        return torch.zeros(poses.shape[0], dtype=torch.float64, device=predicted_depth.device)
    ceiling = config.truncation**2
    residual = predicted_depth.double() - observed_depth.to(predicted_depth.device, torch.float64)
    squared = torch.where(torch.isfinite(residual), residual * residual, torch.full_like(residual, ceiling)).clamp_max(ceiling)
    return log_likelihood_from_errors(squared.sum(dim=-1), count, config.exponent)


def rendered_depth_log_likelihoods(
    poses: torch.Tensor,
    observation: DepthObservation,
    pixels: torch.Tensor,
    render_surface: SurfaceRays,
    config: DepthConfig,
    ray_chunk: int = 65536,
) -> torch.Tensor:
    """The depth term with every particle's depth-camera rays cast into the map.

    Args:
        poses: (N, 4, 4) particle poses ``T_world_cam`` (OpenGL axes: the camera looks along -z).
        observation: the depth image and its camera.
        pixels: (M, 2) depth pixels (u, v) (e.g. :func:`sample_depth_pixels`).
        render_surface: the map: origins (R, 3), directions (R, 3) -> colours, points (R, 3), opacity (R,).
        ray_chunk: rays per render call (``MeasurementConfig.ray_chunk``).
    Returns:
        (N,) float64 log-likelihoods.
    """
    if pixels.ndim != 2 or pixels.shape[-1] != 2:
        raise ValueError(f"pixels: expected shape (M, 2) as (u, v), got {tuple(pixels.shape)}")
    count = pixels.shape[0]
    depth_poses = observation.depth_poses(poses)
    origins, directions = rays_from_poses_and_pixels(depth_poses, pixels, observation.intrinsics)
    axes = depth_poses[:, None, :3, 2].expand_as(directions).reshape(-1, 3)  # each ray's camera +z (the camera looks along -z)
    flat_origins, flat_directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    predicted = []
    with torch.no_grad():
        for start in range(0, len(flat_origins), ray_chunk):
            end = start + ray_chunk
            _, points, opacity = render_surface(flat_origins[start:end], flat_directions[start:end])
            depth = -((points - flat_origins[start:end].to(points)) * axes[start:end].to(points)).sum(dim=-1)
            predicted.append(torch.where(opacity >= _MIN_OPACITY, depth, torch.full_like(depth, torch.nan)))
    predicted_depth = torch.cat(predicted).reshape(poses.shape[0], count)
    u, v = pixels[:, 0].long().cpu(), pixels[:, 1].long().cpu()
    return depth_log_likelihoods(poses, predicted_depth, observation.depth.cpu()[v, u], config)


def read_depth_at(observation: DepthObservation, pixels: torch.Tensor, usable: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """Observed depths at sub-pixel positions: bilinear among the four neighbouring pixels where all four are
    valid readings within ``truncation`` of each other (a smooth surface), else the nearest pixel's reading.

    Nearest-pixel reads alone are off by the depth's slope across half a pixel (centimetres on a surface
    seen at a grazing angle), which drowns the centimetre pose differences a converged cloud has to tell
    apart; across a depth edge or a hole, interpolation would invent a surface, so the nearest reading stays.

    Args:
        pixels: (..., 2) (u, v) in the depth image.
        usable: (...) bool: false where nothing may be read (e.g. behind the camera).
    Returns:
        (...) depths in the observation's dtype, NaN where the position is outside the image, not usable,
        or its reading invalid.
    """
    width, height = observation.intrinsics.width, observation.intrinsics.height
    depth = observation.depth.to(pixels.device).reshape(-1)
    valid = observation.valid(config).to(pixels.device).reshape(-1)
    u, v = pixels[..., 0], pixels[..., 1]
    column, row = u.round(), v.round()
    inside = usable & (column >= 0) & (column <= width - 1) & (row >= 0) & (row <= height - 1)
    nearest = (row.clamp(0, height - 1) * width + column.clamp(0, width - 1)).long()
    read = torch.where(inside & valid[nearest], depth[nearest].to(pixels.dtype), torch.full_like(u, torch.nan))
    left, top = u.floor().clamp(0, max(width - 2, 0)), v.floor().clamp(0, max(height - 2, 0))
    a, b = (u - left).clamp(0, 1), (v - top).clamp(0, 1)
    corner = (top * width + left).long()
    corners = torch.stack((corner, corner + 1, corner + width, corner + width + 1)).clamp(max=width * height - 1)  # (4, ...)
    readings = depth[corners].to(pixels.dtype)
    smooth = inside & valid[corners].all(dim=0) & (readings.amax(dim=0) - readings.amin(dim=0) <= config.truncation) & (width > 1) & (height > 1)
    weights = torch.stack(((1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b))
    return torch.where(smooth, (weights * readings).sum(dim=0), read)


def warped_depth_log_likelihoods(poses: torch.Tensor, points: torch.Tensor, observation: DepthObservation, config: DepthConfig) -> torch.Tensor:
    """The depth term of a converged cloud by re-projecting reference surface points (no rendering).

    Each point X_j moves into each particle's camera; its prediction is the camera-frame depth
    (-z), its observation the depth image at its projection (:func:`read_depth_at`: bilinear on a
    smooth surface, else the nearest pixel). A point behind the camera, outside the image, on a
    pixel without a valid reading, or at infinity (w = 0) counts c².

    Args:
        poses: (N, 4, 4) particle poses ``T_world_cam``.
        points: (M, 4) homogeneous map-frame points (e.g. ``WarpReference.depth_points``).
        observation: the depth image and its camera.
    Returns:
        (N,) float64 log-likelihoods.
    """
    if points.ndim != 2 or points.shape[-1] != 4:
        raise ValueError(f"points: expected shape (M, 4) homogeneous map points, got {tuple(points.shape)}")
    camera = points_in_cameras(observation.depth_poses(poses), points)
    pixels, in_front = project_camera_points(camera, observation.intrinsics)
    surface = (points[:, 3].to(poses.device) != 0)[None]
    return depth_log_likelihoods(poses, -camera[..., 2], read_depth_at(observation, pixels, in_front & surface, config), config)


def reading_points(observation: DepthObservation, pixels: torch.Tensor) -> torch.Tensor:
    """The readings at depth pixels (M, 2) (u, v) as points (M, 3) in the depth camera's frame (OpenGL axes), in the
    pixels' dtype and on their device: ``D(q) · K⁻¹ q̃``."""
    index = pixels.long().to(observation.depth.device)
    readings = observation.depth[index[:, 1], index[:, 0]].to(pixels.device, pixels.dtype)
    return camera_directions_from_pixels(pixels, observation.intrinsics) * readings[:, None]


def surface_distance_log_likelihoods(
    poses: torch.Tensor, observation: DepthObservation, pixels: torch.Tensor, surface_distance: SurfaceDistanceLookup, config: DepthConfig
) -> torch.Tensor:
    """The depth term as the distance of each observed depth point to the map's surface (the likelihood field).

    Pixel q_j with reading D(q_j) is the point p_j = D(q_j) · K⁻¹ q̃_j of the depth camera (OpenGL axes,
    direction z = -1); particle i places it at ``T_world_depth_i · p_j``, and r_ij is that point's distance
    to the nearest surface (``surface_distance``), in the family of :func:`depth_log_likelihoods`.

    Args:
        poses: (N, 4, 4) particle poses ``T_world_cam``.
        observation: the depth image and its camera.
        pixels: (M, 2) depth pixels (u, v) of valid readings (:func:`sample_depth_pixels`).
        surface_distance: the map's lookup, points (..., 3) -> distances (...).
    Returns:
        (N,) float64 log-likelihoods.
    """
    if pixels.ndim != 2 or pixels.shape[-1] != 2:
        raise ValueError(f"pixels: expected shape (M, 2) as (u, v), got {tuple(pixels.shape)}")
    local = reading_points(observation, pixels.to(poses.device, poses.dtype))  # (M, 3)
    depth_poses = observation.depth_poses(poses)
    world = local[None] @ depth_poses[:, :3, :3].transpose(1, 2) + depth_poses[:, None, :3, 3]  # (N, M, 3)
    distances = surface_distance(world).to(torch.float64)
    return depth_log_likelihoods(poses, distances, torch.zeros(pixels.shape[0], dtype=torch.float64, device=distances.device), config)
