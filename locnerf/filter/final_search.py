"""A final local search of the filter's estimate on one image (the cross-entropy method on fixed pixels).

A particle filter on a single image ends with a cloud whose weighted mean is only as good as the
last updates' random pixels let it be: every update draws M fresh pixels, so the likelihood the
cloud follows changes from update to update, and along a valley where the image hardly changes
(on an object seen from outside: the camera shifted sideways and turned to keep the object in
view, or moved along its line of sight) that noise outweighs the signal, and the cloud settles a
few centimetres from the likelihood's peak (docs/RESULTS.md, "Lego: single image": in the failed
trials the truth scored only 1-6 nats above the estimate 5-9 cm away, on 2048 fixed pixels).

The final search holds the likelihood still: it draws ``pixels`` pixels of the image once, by the
measurement's own rule (gradient-weighted where the preset says so: silhouette edges carry the
depth along the line of sight on a plain background), and maximises the same eq. 5 likelihood over
poses near the estimate with the cross-entropy method (Rubinstein 1999; de Boer et al. 2005):
``candidates`` poses ``mean · Exp(δ)``, ``δ ~ N(0, Σ)``, are rendered at those pixels, the
``elite`` best give the next mean and covariance (plus the floors ``min_position`` and
``min_rotation_deg``), ``iterations`` times. The first Σ is the cloud's own covariance scaled by
``inflation²``: the search is shaped like the posterior. A converged cloud is narrower than the
valley it sits in (its spread is the annealed prediction noise's), so with ``pivot_depth`` d the
first round adds swings about the point d ahead of the camera (the object's centre: the sideways
shift with the turn that keeps the object in view), angles ~ N(0, ``pivot_sigma_deg``²) about the
camera's x and y axes, as the motion model's pivot noise draws them
(:class:`locnerf.filter.motion.PivotNoise`). The result is the best pose seen (the previous mean is
always one of the candidates, so the result never scores below the filter's estimate on those pixels).

Cost: ``pixels × (1 + iterations × candidates)`` rays, once per image.

:func:`cross_entropy_search` is the search itself on any likelihood of fixed pixels; the live filter
runs it after a relocalization on an update's own likelihood (:mod:`locnerf.filter.recovery`, ``search``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from pydantic import Field

from locnerf.filter.initialization import gaussian_particles
from locnerf.filter.measurement import RenderRays, observed_colours, particle_log_likelihoods, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.motion import PivotNoise
from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.geometry.averaging import weighted_pose_mean_and_covariance
from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics


class FinalSearchConfig(CrossEntropyConfig):
    """The final local search of a single image: the cross-entropy search on ``pixels`` pixels drawn once."""

    pixels: int = Field(1024, ge=1, description="Pixels drawn once (by the measurement's sampling rule) and rendered for every candidate.")


@dataclass(frozen=True)
class FinalSearchResult:
    """The searched pose and what it cost."""

    pose: torch.Tensor
    """(4, 4) float64 best pose found."""
    log_likelihood: float
    """Its eq. 5 log-likelihood on the search's pixels."""
    start_log_likelihood: float
    """The starting mean's, on the same pixels."""
    rays: int


def final_search(
    mean: torch.Tensor,
    covariance: torch.Tensor,
    image: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    render_rays: RenderRays,
    measurement: MeasurementConfig,
    config: FinalSearchConfig,
    generator: torch.Generator,
    device: torch.device | str = "cpu",
) -> FinalSearchResult:
    """Maximise the likelihood of ``image`` near ``mean`` by the cross-entropy method (module docstring).

    Args:
        mean: (4, 4) the filter's estimate (``T_world_cam``).
        covariance: (6, 6) the cloud's covariance in the tangent space of ``mean`` (rotation first),
            as :class:`locnerf.filter.estimate.ParticleEstimate` gives it.
        image: (H, W, 3) observed colours in [0, 1].
        intrinsics: the camera that took ``image``.
        render_rays: the map.
        measurement: the likelihood's exponent, sampling rule, ray chunk and exposure model.
        config: the search's budget and spreads.
        generator: CPU generator of every draw.
        device: where the poses are rendered from.
    """
    pixels = sample_pixels_of_image(image, measurement, generator, config.pixels)
    observed = observed_colours(image, pixels).to(device)
    pixels = pixels.to(device)

    def score(poses: torch.Tensor) -> torch.Tensor:
        return particle_log_likelihoods(
            poses.to(device, torch.float32),
            pixels,
            observed,
            intrinsics,
            render_rays,
            measurement.exponent,
            measurement.ray_chunk,
            measurement.exposure_gain_range,
        ).cpu()

    return cross_entropy_search(mean, covariance, score, config, generator, len(pixels))


def first_round_covariance(config: CrossEntropyConfig, covariance: torch.Tensor) -> torch.Tensor:
    """(6, 6) float64 covariance of the first round from the cloud's (6, 6), rotation first: inflated, plus the
    pivot swings (:func:`valley_covariance`), the start spreads and the floors."""
    covariance = covariance.double().cpu()
    start = torch.tensor([math.radians(config.start_rotation_deg)] * 3 + [config.start_position] * 3, dtype=torch.float64)
    return config.inflation**2 * 0.5 * (covariance + covariance.T) + valley_covariance(config) + torch.diag(start**2) + floor_covariance(config)


def valley_covariance(config: CrossEntropyConfig) -> torch.Tensor:
    """(6, 6) float64 covariance of the swings about the pivot point (zero without ``pivot_depth``), rotation first."""
    if config.pivot_depth is None:
        return torch.zeros(6, 6, dtype=torch.float64)
    return PivotNoise.equal_swings(config.pivot_depth, config.pivot_sigma_deg).covariance()


def floor_covariance(config: CrossEntropyConfig) -> torch.Tensor:
    """(6, 6) float64 diagonal covariance of the floors, rotation first."""
    sigmas = [math.radians(config.min_rotation_deg)] * 3 + [config.min_position] * 3
    return torch.diag(torch.tensor(sigmas, dtype=torch.float64) ** 2)


def cross_entropy_search(
    mean: torch.Tensor,
    covariance: torch.Tensor,
    score: Callable[[torch.Tensor], torch.Tensor],
    config: CrossEntropyConfig,
    generator: torch.Generator,
    rays_per_pose: int = 0,
) -> FinalSearchResult:
    """Maximise ``score`` near ``mean`` by the cross-entropy method (module docstring).

    Args:
        mean: (4, 4) start (``T_world_cam``).
        covariance: (6, 6) the cloud's covariance in the tangent space of ``mean`` (rotation first).
        score: poses (K, 4, 4) float64 on the CPU -> (K,) log-likelihoods on fixed pixels (NaN: impossible).
        config: the search's budget and spreads.
        generator: CPU generator of every draw.
        rays_per_pose: rays one score of one pose costs (for the reported ``rays``).
    """
    validate_poses(mean, name="cross-entropy search start")
    if mean.ndim != 2 or tuple(covariance.shape) != (6, 6):
        raise ValueError(f"cross-entropy search: expected a (4, 4) mean and a (6, 6) covariance, got {tuple(mean.shape)} and {tuple(covariance.shape)}")
    mean = mean.double().cpu()
    covariance = first_round_covariance(config, covariance)
    best_pose, best_score = mean, float(score(mean[None])[0])
    start_score = best_score
    rays = rays_per_pose
    for _ in range(config.iterations):
        candidates = torch.cat((mean[None], gaussian_particles(mean, covariance, config.candidates - 1, generator)))
        scores = score(candidates).double().cpu()
        rays += len(candidates) * rays_per_pose
        elite = torch.topk(torch.nan_to_num(scores, nan=-math.inf), config.elite).indices
        if float(scores[elite[0]]) > best_score:
            best_pose, best_score = candidates[elite[0]], float(scores[elite[0]])
        mean, covariance = weighted_pose_mean_and_covariance(candidates[elite])
        covariance = covariance + floor_covariance(config)
    return FinalSearchResult(best_pose, best_score, start_score, rays)
