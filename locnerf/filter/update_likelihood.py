"""One synchronous update's likelihood as a function of poses, on pixels drawn once.

The localizer weighs its snapshot with it, and a search of the estimate (``recovery.search``) scores
its candidate poses with the same function: the same colour pixels (or re-projection reference) and
the same depth pixels, so that the search climbs the likelihood the update weighed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from locnerf.filter.depth_measurement import (
    DepthObservation,
    SurfaceDistanceLookup,
    rendered_depth_log_likelihoods,
    sample_depth_pixels,
    surface_distance_log_likelihoods,
    warped_depth_log_likelihoods,
)
from locnerf.filter.measurement import RenderRays, observed_colours, particle_log_likelihoods, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.warp import SurfaceRays, WarpReference, render_reference, warp_log_likelihoods
from locnerf.render.camera import PinholeIntrinsics

PoseScore = Callable[[torch.Tensor], torch.Tensor]
"""Poses (K, 4, 4) on the update's device -> (K,) log-likelihoods."""


@dataclass(frozen=True)
class UpdateLikelihood:
    """One update's log-likelihood on fixed pixels (and reference, depth points).

    Attributes:
        score: poses (K, 4, 4) on the update's device -> (K,) log-likelihoods.
        rays_per_pose: rays rendered for each pose scored.
        fixed_rays: rays rendered once for the update (a re-projection's reference).
        warped: the colour term re-projects a reference render (:mod:`locnerf.filter.warp`).
        depth_term: the depth term of ``score`` alone (None: colour only), for a search on its own colour pixels.
        depth_rays: rays the depth term renders per pose.
    """

    score: PoseScore
    rays_per_pose: int
    fixed_rays: int
    warped: bool
    depth_term: PoseScore | None = None
    depth_rays: int = 0


def with_depth(colour: PoseScore, depth_term: PoseScore | None) -> PoseScore:
    """The colour term plus the depth term (per pose; ``colour`` alone when there is none)."""
    if depth_term is None:
        return colour

    def score(poses: torch.Tensor) -> torch.Tensor:
        values = colour(poses)
        return values + depth_term(poses).to(values)

    return score


def search_likelihood(
    likelihood: UpdateLikelihood,
    pixels: torch.Tensor | None,
    observed: torch.Tensor | None,
    config: MeasurementConfig,
    intrinsics: PinholeIntrinsics,
    render_rays: RenderRays,
    device: torch.device,
) -> tuple[PoseScore, int]:
    """What a search of the update scores, and its rays per pose: the update's likelihood, or with a search's own
    colour ``pixels`` (M, 2) and ``observed`` colours (M, 3) (:func:`locnerf.filter.cloud_search.with_own_pixels`)
    those rendered in place of the update's colour term, its depth term kept."""
    if pixels is None or observed is None:
        return likelihood.score, likelihood.rays_per_pose
    colour = _rendered_colour(pixels, observed, config, intrinsics, render_rays, device)
    return with_depth(colour, likelihood.depth_term), len(pixels) + likelihood.depth_rays


def _rendered_colour(
    pixels: torch.Tensor, observed: torch.Tensor, config: MeasurementConfig, intrinsics: PinholeIntrinsics, render_rays: RenderRays, device: torch.device
) -> PoseScore:
    """The colour term of ``pixels`` (M, 2) seen as ``observed`` (M, 3), rendered from every pose."""
    on_device, colours = pixels.to(device), observed.to(device)

    def colour(poses: torch.Tensor) -> torch.Tensor:
        return particle_log_likelihoods(poses, on_device, colours, intrinsics, render_rays, config.exponent, config.ray_chunk, config.exposure_gain_range)

    return colour


def update_likelihood(
    config: MeasurementConfig,
    generator: torch.Generator,
    device: torch.device,
    particles: int,
    reference_pose: torch.Tensor | None,
    image: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    render_rays: RenderRays,
    render_surface: SurfaceRays | None,
    depth: DepthObservation | None,
    surface_distance: SurfaceDistanceLookup | None,
) -> UpdateLikelihood:
    """The likelihood of an update of ``particles`` particles on ``image`` (H, W, 3): by re-projection of one
    reference render at ``reference_pose`` (4, 4; ``render_surface`` needed), else by rendering
    ``config.pixels_for(particles)`` pixels drawn once; plus the depth term of ``depth`` when given (the caller
    checks that the map offers what the settings need)."""
    reference = None
    if reference_pose is not None:
        looked_up = config.depth is not None and config.depth.likelihood == "surface_distance"
        depth_pixels = config.depth.pixels if depth is not None and not looked_up else 0
        depth_camera, T_cam_depth = (depth.intrinsics, depth.T_cam_depth) if depth is not None else (None, None)
        reference = render_reference(render_surface, reference_pose, intrinsics, config, generator, depth_pixels, depth_camera, T_cam_depth)
        observed_image = image.to(device)

        def colour(poses: torch.Tensor) -> torch.Tensor:
            return warp_log_likelihoods(poses, reference, observed_image, intrinsics, config.exponent, config.exposure_gain_range)

        colour_rays, fixed_rays = 0, reference.rays
    else:
        pixels = sample_pixels_of_image(image, config, generator, config.pixels_for(particles))
        colour = _rendered_colour(pixels, observed_colours(image, pixels), config, intrinsics, render_rays, device)
        colour_rays, fixed_rays = len(pixels), 0
    if depth is None:
        return UpdateLikelihood(colour, colour_rays, fixed_rays, reference is not None)
    depth_term, depth_rays = _depth_term(config, generator, device, depth, reference, render_surface, surface_distance)
    return UpdateLikelihood(with_depth(colour, depth_term), colour_rays + depth_rays, fixed_rays, reference is not None, depth_term, depth_rays)


def _depth_term(
    config: MeasurementConfig,
    generator: torch.Generator,
    device: torch.device,
    depth: DepthObservation,
    reference: WarpReference | None,
    render_surface: SurfaceRays | None,
    surface_distance: SurfaceDistanceLookup | None,
) -> tuple[PoseScore, int]:
    """The depth term on pixels drawn once, and the rays it renders per pose: looked up in the surface-distance
    layer (``likelihood = "surface_distance"``), else re-projected from the ``reference`` of a warped update,
    else rendered from every pose."""
    if config.depth.likelihood == "surface_distance":
        pixels = sample_depth_pixels(depth, config.depth, generator).to(device)
        return lambda poses: surface_distance_log_likelihoods(poses, depth, pixels, surface_distance, config.depth), 0
    if reference is not None:
        return lambda poses: warped_depth_log_likelihoods(poses, reference.depth_points, depth, config.depth), 0
    pixels = sample_depth_pixels(depth, config.depth, generator).to(device)
    return lambda poses: rendered_depth_log_likelihoods(poses, depth, pixels, render_surface, config.depth, config.ray_chunk), len(pixels)
