"""A search of the relocalized cloud (``recovery.search``): where it starts, and how far it moves the cloud.

The search itself is :func:`locnerf.filter.final_search.cross_entropy_search` on an update's own likelihood;
the localizer asks for one after its refining updates (:meth:`locnerf.filter.localizer.Localizer.search_for`)
and moves its particles by the find (:meth:`locnerf.filter.localizer.Localizer.move_by_search`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import torch

from locnerf.filter.final_search import FinalSearchResult
from locnerf.filter.measurement import observed_colours, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.filter.particles import weighted_position_spread
from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.geometry.averaging import weighted_pose_mean_and_covariance
from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.geometry.se3 import pose_inverse

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PoseSearch:
    """A search an update carries (``recovery.search``): from ``mean`` (4, 4) float64 with the cloud's
    ``covariance`` (6, 6) float64 (tangent space, rotation first), both of the update's snapshot, its draws
    seeded by ``seed``; ``moved`` (4, 4) float64 is the product of the searches' moves of the cloud before the
    snapshot (:func:`search_move` discounts those that came after it). With ``config.pixels`` the search
    scores its own colour ``pixels`` (M, 2) float32 (u, v) with their ``observed`` colours (M, 3) float32 in
    [0, 1] (:func:`with_own_pixels`); None: the update's."""

    config: CrossEntropyConfig
    mean: torch.Tensor
    covariance: torch.Tensor
    seed: int
    moved: torch.Tensor
    pixels: torch.Tensor | None = None
    observed: torch.Tensor | None = None


def cloud_within(poses: torch.Tensor, weights: torch.Tensor, max_spread: float) -> bool:
    """Whether the cloud (N, 4, 4) with weights (N,) has a largest per-axis weighted position spread of at most ``max_spread``."""
    return weighted_position_spread(poses[:, :3, 3].double().cpu(), weights.double().cpu()) <= max_spread


def pose_search(config: CrossEntropyConfig, poses: torch.Tensor, weights: torch.Tensor, seed: int, moved: torch.Tensor) -> PoseSearch:
    """The search from the weighted mean and covariance of the snapshot's poses (N, 4, 4) with weights (N,)."""
    mean, covariance = weighted_pose_mean_and_covariance(poses.double().cpu(), weights.double().cpu())
    return PoseSearch(config, mean, covariance, seed, moved.clone())


def with_own_pixels(search: PoseSearch, image: torch.Tensor, measurement: MeasurementConfig, generator: torch.Generator) -> PoseSearch:
    """``search`` with ``search.config.pixels`` colour pixels of ``image`` (H, W, 3) in [0, 1] drawn for it by the
    measurement's sampling rule (:func:`locnerf.filter.measurement.sample_pixels_of_image`), and their colours;
    unchanged when the config asks for none.

    An update's own colour pixels are as many as its particle count leaves (``measurement.ray_budget``: 32 to 128
    in the kitchen files), too few for colour alone to tell the turn and sideways shift that keep the view;
    hundreds, held still over the search's rounds, do (docs/FILTER.md, "Relocalization after a detected kidnapping")."""
    if search.config.pixels is None:
        return search
    pixels = sample_pixels_of_image(image, measurement, generator, search.config.pixels)
    return dataclasses.replace(search, pixels=pixels, observed=observed_colours(image, pixels))


def search_move(search: PoseSearch, found: FinalSearchResult, moved: torch.Tensor, min_gain: float) -> torch.Tensor | None:
    """The move (4, 4) float64 that puts the snapshot's mean on ``found``, or None when the find scores under
    ``min_gain`` nats above the mean.

    The move is ``C = found · mean⁻¹ · D⁻¹``, to compose on the left of every particle (the world frame's: the
    odometry composed on the right since the snapshot stays), ``D = moved · search.moved⁻¹`` the searches' moves
    made since the snapshot (``moved``: their product now): a cloud that an earlier search already moved is not
    moved twice."""
    gain = found.log_likelihood - found.start_log_likelihood
    accepted = gain >= min_gain and math.isfinite(gain)
    logger.info(
        "search: best pose %.3f map units, %.2f deg from the estimate, %.2f nats above it: %s",
        float(translation_error(found.pose, search.mean)),
        float(rotation_error_deg(found.pose, search.mean)),
        gain,
        "moving the cloud" if accepted else "kept",
    )
    if not accepted:
        return None
    since = moved @ pose_inverse(search.moved)
    return found.pose.double().cpu() @ pose_inverse(search.mean.double().cpu()) @ pose_inverse(since)
