"""The measurement of a converged cloud by re-projection: render once, weigh every particle by warping.

Once the particles cluster around one pose, rendering the same M pixels from each of N nearly equal
poses costs N·M rays for N nearly equal images. Instead (as direct visual odometry compares a
keyframe with a new image), the reference pose x_ref, the cluster's weighted mean, is rendered once
at every ``stride``-th pixel, and M of those pixels are kept (drawn by that render's gradient, away
from the far sides of depth edges): each gives a colour c_j and the point X_j where its ray meets
the map (its expected surface point; a ray that met nothing, or less than ``min_opacity`` of it, is
a direction at infinity). A particle x_i is right when the observed image I shows c_j where X_j
projects from x_i, so its residuals are ``I(π(x_i⁻¹ X_j)) − c_j``, with I sampled bilinearly
(sub-pixel positions count: a pose error of a fraction of a pixel changes the residual smoothly).
The likelihood is eq. 5's, ``(M / SSE_i)^γ`` over these residuals (with the optional exposure fit).

Cost: H·W / stride² rays plus N·M projections and bilinear lookups, instead of N·M rays, so a
converged cloud can keep many particles and many pixels. What it leaves out: occlusions that differ between x_ref
and x_i (a point hidden from x_i still counts), and the map's view dependence; both vanish as the
cloud tightens, which is why it is used only below ``max_spread`` (and ``max_rotation_spread_deg``).
A point that projects behind a particle's camera, or outside its image, reads the image's nearest
border pixel (``grid_sample``'s border padding): the residual stays defined and the same M terms
weigh every particle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from locnerf.filter.measurement import draw_uniformly, photometric_log_likelihoods, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig, WarpConfig
from locnerf.filter.particles import weighted_position_spread
from locnerf.geometry.averaging import weighted_pose_mean_and_covariance
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import SurfaceRays
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels

# Camera-frame depth (OpenGL: -z) below which a point is treated as behind the camera.
_MIN_DEPTH = 1e-6
_ROTATION_MEAN_TOLERANCE = 1e-7
DEPTH_BORDER = 0.05
"""Fraction of the depth image's width and height, at each side, where reference depth points are not drawn."""


@dataclass(frozen=True)
class WarpReference:
    """What the reference render gives the warp.

    Attributes:
        colours: (M, 3) rendered colours c_j.
        points: (M, 4) homogeneous map-frame points: (X_j, 1) for a surface, (d_j, 0) for a direction at infinity.
        rays: how many rays the reference render took.
        depth_points: (K, 4) homogeneous map-frame surface points (w = 1) for the depth term
            (:func:`locnerf.filter.depth_measurement.warped_depth_log_likelihoods`), drawn uniformly
            among the render's surface pixels; (0, 4) when none were asked for.
    """

    colours: torch.Tensor
    points: torch.Tensor
    rays: int = 0
    depth_points: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 4))


def warp_reference_pose(poses: torch.Tensor, weights: torch.Tensor, config: WarpConfig) -> torch.Tensor | None:
    """The reference pose (4, 4) float64 of a cloud tight enough to warp: its weighted mean; None when too spread.

    Args:
        poses: (N, 4, 4) particle poses.
        weights: (N,) normalised weights.
    """
    poses, w = poses.double().cpu(), weights.double().cpu()
    w = w / w.sum()
    if weighted_position_spread(poses[:, :3, 3], w) > config.max_spread:
        return None
    mean, covariance = weighted_pose_mean_and_covariance(poses, w, _ROTATION_MEAN_TOLERANCE)
    rotation_spread = math.degrees(math.sqrt(float(covariance.diagonal()[:3].max().clamp_min(0))))
    return mean if rotation_spread <= config.max_rotation_spread_deg else None


def render_reference(
    render_surface: SurfaceRays,
    pose: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    measurement: MeasurementConfig,
    generator: torch.Generator,
    depth_pixels: int = 0,
    depth_camera: PinholeIntrinsics | None = None,
    T_cam_depth: torch.Tensor | None = None,
) -> WarpReference:
    """Render the reference view at every ``warp.stride``-th pixel and keep M = ``warp.pixels`` of them
    (all of them when the lattice has fewer, as a small, downscaled camera may).

    The M are drawn from that coarse render as the measurement draws pixels from an observed image
    (``measurement.sampling``: by the render's gradient), so they sit where the map has texture and
    edges *as seen from the reference*: the observed image's gradient pixels would, from a reference
    a few pixels off, mostly land on flat map regions and tell the particles apart by noise alone.

    Args:
        pose: (4, 4) reference camera pose ``T_world_cam``.
        measurement: its ``warp`` must be set.
        depth_pixels: how many surface points to draw for the depth term (``depth_points``), uniformly
            among the pixels that met a surface and, with ``depth_camera``,
            project into the depth image from the reference pose at least ``DEPTH_BORDER`` of its size
            from its border (drawn after the M, so the M do not depend on them); 0: none.
        depth_camera: the depth camera; None: no check against its view.
        T_cam_depth: (4, 4) the depth camera's pose in the camera's frame; None: it sits at the pose.

    A depth point outside a particle's depth image counts as the largest residual, so points near the
    border of the depth camera's view (narrower than the colour camera's on a Kinect) would favour
    particles that bring more of them into view, whatever their depths say: the border keeps them out.
    """
    warp = measurement.warp
    if warp is None:
        raise ValueError("render_reference: measurement.warp is None; expected a WarpConfig")
    lattice = pixel_grid(intrinsics, device=pose.device).reshape(intrinsics.height, intrinsics.width, 2)[:: warp.stride, :: warp.stride]
    rows, columns = lattice.shape[0], lattice.shape[1]
    pixels = lattice.reshape(-1, 2).float()
    origins, directions = rays_from_poses_and_pixels(pose[None].float(), pixels, intrinsics)
    colours, points, opacity = render_surface(origins[0], directions[0])
    seen = opacity >= warp.min_opacity
    camera_depth = ((points - pose[:3, 3].to(points)) @ pose[:3, 2].to(points)).neg()  # along the optical axis (-z)
    depth = torch.where(seen, camera_depth, torch.full_like(camera_depth, torch.inf)).reshape(rows, columns)
    eligible = ~beyond_an_edge(depth, warp.occlusion_margin, math.ceil(warp.occlusion_pixels / warp.stride))
    coarse = colours.reshape(rows, columns, 3)
    chosen = sample_pixels_of_image(coarse.cpu(), measurement, generator, warp.pixels, eligible.reshape(-1))
    index = (chosen[:, 1].long() * columns + chosen[:, 0].long()).to(colours.device)
    surface = seen[index, None]
    homogeneous = torch.where(
        surface,
        torch.cat((points[index], torch.ones_like(surface, dtype=points.dtype)), dim=-1),
        torch.cat((directions[0].to(points.device, points.dtype)[index], torch.zeros_like(surface, dtype=points.dtype)), dim=-1),
    )
    depth_pose = pose if T_cam_depth is None else pose @ T_cam_depth.to(pose)
    depth_points = reference_depth_points(points, seen, depth_pose, depth_pixels, depth_camera, generator)
    return WarpReference(colours[index].float(), homogeneous.float(), len(pixels), depth_points)


def reference_depth_points(
    points: torch.Tensor, seen: torch.Tensor, pose: torch.Tensor, count: int, depth_camera: PinholeIntrinsics | None, generator: torch.Generator
) -> torch.Tensor:
    """``count`` of the reference render's surface points for the depth term (:func:`render_reference`).

    Args:
        points: (R, 3) the render's expected surface points; seen: (R,) bool, those that met a surface.
        pose: (4, 4) the depth camera's pose at the reference.
    Returns:
        (count, 4) float32 homogeneous points (w = 1), drawn uniformly among the seen ones that project
        at least ``DEPTH_BORDER`` inside the depth image (all seen ones without ``depth_camera``);
        (0, 4) when ``count`` is 0 or none qualifies.
    """
    if count == 0:
        return torch.zeros(0, 4)
    candidates = seen.clone()
    homogeneous = torch.cat((points, torch.ones_like(points[:, :1])), dim=-1)
    if depth_camera is not None:
        projected, in_front = project_points(pose[None].to(points), homogeneous, depth_camera)
        margin = torch.tensor([depth_camera.width, depth_camera.height], dtype=points.dtype, device=points.device) * DEPTH_BORDER
        far_corner = torch.tensor([depth_camera.width - 1, depth_camera.height - 1], dtype=points.dtype, device=points.device) - margin
        candidates &= in_front[0] & ((projected[0] >= margin) & (projected[0] <= far_corner)).all(dim=-1)
    eligible = torch.nonzero(candidates.cpu()).reshape(-1)
    if len(eligible) == 0:
        return torch.zeros(0, 4)
    return homogeneous[draw_uniformly(eligible, count, generator).to(points.device)].float()


def beyond_an_edge(depth: torch.Tensor, margin: float, radius: int) -> torch.Tensor:
    """Pixels on the far side of a depth edge: (h, w) depths (inf: nothing) -> (h, w) bool, true where
    a pixel within ``radius`` (Chebyshev) is closer than ``(1 - margin)`` times the pixel's depth."""
    if radius == 0:
        return torch.zeros_like(depth, dtype=torch.bool)
    nearest = -F.max_pool2d(-depth[None, None], kernel_size=2 * radius + 1, stride=1, padding=radius)[0, 0]
    return nearest < depth * (1.0 - margin)


def points_in_cameras(poses: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Homogeneous map-frame points (M, 4) (w = 0: directions) in the frame of every camera
    ``T_world_cam`` (N, 4, 4): ``R^T (X - w t)`` -> (N, M, 3) (OpenGL axes: depth is -z)."""
    rotation = poses[:, :3, :3]
    translation = poses[:, :3, 3]
    points = points.to(poses.device, poses.dtype)
    relative = points[None, :, :3] - points[None, :, 3:] * translation[:, None, :]
    return torch.einsum("nji,nmj->nmi", rotation, relative)


def project_points(poses: torch.Tensor, points: torch.Tensor, intrinsics: PinholeIntrinsics) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel coordinates of homogeneous map-frame points seen from every pose.

    Args:
        poses: (N, 4, 4) ``T_world_cam`` (OpenGL camera axes).
        points: (M, 4) homogeneous points (w = 0: directions).
    Returns:
        (N, M, 2) (u, v) in the pixel convention of :mod:`locnerf.render.rays` (inverse of its
        rays), and (N, M) bool: in front of the camera.
    """
    return project_camera_points(points_in_cameras(poses, points), intrinsics)


def project_camera_points(camera: torch.Tensor, intrinsics: PinholeIntrinsics) -> tuple[torch.Tensor, torch.Tensor]:
    """Pinhole projection of camera-frame points (..., 3) (OpenGL axes) -> (..., 2) (u, v) and (...) bool: in front of the camera."""
    depth = -camera[..., 2]
    in_front = depth > _MIN_DEPTH
    safe_depth = torch.where(in_front, depth, torch.ones_like(depth))
    u = intrinsics.cx + intrinsics.fx * camera[..., 0] / safe_depth
    v = intrinsics.cy - intrinsics.fy * camera[..., 1] / safe_depth
    return torch.stack((u, v), dim=-1), in_front


def sample_image(image: torch.Tensor, pixels: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Bilinear colours of ``image`` (H, W, 3) at sub-pixel ``pixels`` (N, M, 2) (u, v) -> (N, M, 3);
    outside the image, and where ``valid`` (N, M) is false, the nearest border pixel."""
    height, width = image.shape[0], image.shape[1]
    scale = torch.tensor([2.0 / max(width - 1, 1), 2.0 / max(height - 1, 1)], device=pixels.device, dtype=pixels.dtype)
    grid = pixels * scale - 1.0
    grid = torch.where(valid[..., None], grid, torch.full_like(grid, -2.0))
    planar = image.to(pixels.device, pixels.dtype).permute(2, 0, 1)[None]
    sampled = F.grid_sample(planar, grid[None], mode="bilinear", padding_mode="border", align_corners=True)
    return sampled[0].permute(1, 2, 0)


def warped_observations(poses: torch.Tensor, reference: WarpReference, image: torch.Tensor, intrinsics: PinholeIntrinsics) -> torch.Tensor:
    """The observed colours at each reference point's projection from each pose: (N, 4, 4) -> (N, M, 3)."""
    pixels, in_front = project_points(poses, reference.points, intrinsics)
    return sample_image(image, pixels, in_front)


def warp_log_likelihoods(
    poses: torch.Tensor,
    reference: WarpReference,
    image: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    exponent: float = 4.0,
    exposure_gain_range: tuple[float, float] | None = None,
) -> torch.Tensor:
    """Log-likelihood of every particle by re-projecting the reference points into its view.

    Args:
        poses: (N, 4, 4) particle poses in the map frame.
        reference: the reference render (:func:`render_reference`).
        image: (H, W, 3) observed image in [0, 1], seen with ``intrinsics``.
        exponent: γ of eq. 5.
        exposure_gain_range: as in :func:`locnerf.filter.measurement.particle_log_likelihoods`
            (the gain and bias fitted per particle map the reference colours onto its warped observations).
    Returns:
        (N,) float64 log-likelihoods.
    """
    if image.ndim != 3 or image.shape[-1] != 3 or (image.shape[0], image.shape[1]) != (intrinsics.height, intrinsics.width):
        raise ValueError(f"image: expected shape ({intrinsics.height}, {intrinsics.width}, 3) for the intrinsics, got {tuple(image.shape)}")
    observed = warped_observations(poses, reference, image, intrinsics)
    return photometric_log_likelihoods(reference.colours.to(observed.device, observed.dtype), observed, exponent, exposure_gain_range)
