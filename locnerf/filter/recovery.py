"""Recovery from kidnapping: augmented MCL (Thrun, Burgard & Fox, Probabilistic Robotics, §8.3.5).

Two exponential averages of the mean measurement likelihood are kept, a slow one and a fast one:
``w_slow += α_slow (w_avg − w_slow)``, ``w_fast += α_fast (w_avg − w_fast)``. After each update a
fraction ``max(0, 1 − e^τ w_fast / w_slow)`` of the particles is replaced by fresh ones: when the
recent likelihood falls well below the long-term one, the filter is probably lost. Everything is
kept in log space because eq. 5's likelihoods span hundreds of orders of magnitude. Off by default,
as in amcl.

Two departures from the textbook, both for eq. 5's sharp likelihood (a power γ = 4 of an inverse
squared error): the likelihood fed to the averages is the best particle's, not the mean (the
localizer's choice, see ``ancestor_scores.best_weighed_log_likelihood``), and a drop of up to ``τ`` nats
(``tolerance``) is tolerated, since a few nats separate a view seen from 2 cm off from one seen
exactly, or a plain wall from a textured one; τ = 0 is augmented MCL. Optionally (``average = "log"``)
the averages are of the log-likelihoods, a geometric mean: one sharp update lifts the average of the
likelihoods to within log(1/α) nats of itself, and the next ordinary updates then read as a drop.
Where the likelihood cannot tell a dip (a dark or blurred stretch) from a kidnapping, the keyframe index can:
with ``place_check_views`` > 0 a low update counts toward a detection only when none of the keyframes most
like its image lies near the estimate (:func:`place_recognized`).

Where the fresh particles go: when the update's image was matched against the map's keyframes
(:mod:`locnerf.filter.keyframes`), a share ``keyframe_share`` is drawn around the best-matching
keyframes (Gaussian, ``keyframe_position_sigma`` × the keyframes' spacing per axis and
``keyframe_rotation_sigma_deg`` per axis, in the keyframe's frame; or, with ``keyframe_orbit_depth``
> 0, circling what the keyframe looks at, see :func:`keyframe_orbit_particles`). Of the others, a share
``local_share`` is drawn around the current estimate (a position cube of half side ``r_k``, a yaw
offset within ``±ψ_k``, the estimate's roll and pitch), the rest uniformly over the search region
(uniform yaw, the estimate's roll and pitch). ``r_k``
and ``ψ_k`` grow geometrically with the number ``k`` of consecutive updates that injected:
``r_k = min(r_max, r_0 g^k)``, ``ψ_k = min(180°, ψ_0 g^k)``. A small jump (a slip, a drift that
ran away) is found by the first, dense local draws; a large one by the later, wider ones or by the
uniform share, whose density does not depend on how long the filter has been lost.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from locnerf.filter.estimate import ParticleEstimate
from locnerf.filter.initialization import gaussian_particles, global_particles, rotation_about_axis, uniform_particles
from locnerf.filter.motion import PivotNoise
from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.geometry.se3 import make_pose, se3_exp

logger = logging.getLogger(__name__)


class RecoveryConfig(BaseModel):
    """Augmented-MCL injection of fresh particles, around the estimate and over the search region."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(False, description="Inject fresh particles when the likelihood collapses.")
    alpha_slow: float = Field(0.05, gt=0, le=1, description="Rate of the long-term likelihood average (per update).")
    alpha_fast: float = Field(0.5, gt=0, le=1, description="Rate of the short-term likelihood average (per update).")
    average: Literal["likelihood", "log"] = Field(
        "likelihood",
        description="What the averages average: the likelihoods (augmented MCL; one sharp update lifts the slow average by nats) "
        "or their logs (a geometric mean: the slow level follows the typical update, not the best one).",
    )
    max_fraction: float = Field(0.5, ge=0, le=1, description="Upper bound on the fraction of particles replaced per update.")
    tolerance: float = Field(
        0.0,
        ge=0,
        description="Drop (nats) of the fast average below the slow one that is tolerated: the fraction is 1 − (w_fast/w_slow)·e^tolerance (0: augmented MCL).",
    )
    confirm_updates: int = Field(
        1,
        ge=1,
        description="Consecutive updates whose likelihood must fall below the tolerated drop before particles are injected "
        "(1: at once, as augmented MCL; 2 ignores a single outlying update at the cost of one update's delay).",
    )
    local_share: float = Field(
        0.5, ge=0, le=1, description="Share of the injected particles drawn around the current estimate; the rest are uniform over the search region."
    )
    local_radius: float = Field(
        0.1, gt=0, description="r_0: half side (map units) of the position cube around the estimate at the first injecting update of a streak."
    )
    local_yaw_deg: float = Field(
        10.0, ge=0, le=180, description="ψ_0: bound (degrees) of the yaw offset from the estimate at the first injecting update of a streak."
    )
    local_growth: float = Field(1.5, ge=1, description="g: factor by which the local radius and yaw bound grow with each further consecutive injecting update.")
    local_max_radius: float = Field(2.0, gt=0, description="r_max: upper bound on the local radius, map units.")
    keyframe_share: float = Field(
        0.0, ge=0, le=1, description="Share of the injected particles drawn around the keyframes that best match the image (when a keyframe index is given)."
    )
    keyframe_count: int = Field(8, ge=1, description="How many best-matching keyframes the keyframe share is spread over (equally).")
    place_check_views: int = Field(
        0,
        ge=0,
        description="A low update counts toward a detection only when none of this many keyframes most like its image (at most "
        "keyframe_count) lies within place_check_position and place_check_rotation_deg of the estimate: an image that still looks like "
        "where the filter believes it is marks a dip in the likelihood (a dark or blurred stretch), not a kidnapping (0: no check).",
    )
    place_check_position: float = Field(0.4, gt=0, description="Place check: how far (map units) a matching keyframe may lie from the estimate.")
    place_check_rotation_deg: float = Field(30.0, gt=0, description="Place check: how far a matching keyframe may be turned from the estimate, degrees.")
    keyframe_position_sigma: float = Field(
        0.5, gt=0, description="Position standard deviation around a keyframe per axis, as a multiple of the keyframes' spacing."
    )
    keyframe_position_sigma_map: float | None = Field(
        None,
        gt=0,
        description="Position spread around a keyframe in map units instead of keyframe_position_sigma spacings (None: spacings). "
        "For maps whose keyframes lie millimetres apart along one path (the kitchen's: 6 mm) while the robot may be decimetres from all of them.",
    )
    keyframe_rotation_sigma_deg: float = Field(5.0, ge=0, description="Rotation standard deviation around a keyframe per axis, degrees.")
    keyframe_orbit_depth: float = Field(
        0.0,
        ge=0,
        description="Orbit draws (keyframe_orbit_particles): distance (map units) ahead of a keyframe of the point the draws circle, "
        "level, at about the keyframe's distance; keyframe_position_sigma is then the spread along the circles (0: Gaussian draws).",
    )
    keyframe_orbit_distance_sigma: float = Field(
        0.0, ge=0, description="Orbit draws: standard deviation of the change of distance to the circled point, map units."
    )
    reference_views: bool = Field(
        False,
        description="With keyframe_start.lattice: the keyframe index holds the map's reference views (its training cameras) after the lattice's, "
        "so that a start on the training path finds them and recovery finds a place anywhere in the room (locnerf.maps.keyframes.joined_index).",
    )
    relocalize_updates: int = Field(
        0,
        ge=0,
        description="After an update that injects, this many updates refine around the posterior (refine_*) instead of testing the likelihood; "
        "then the likelihood averages start afresh (0: test every update, as augmented MCL).",
    )
    verify_updates: int = Field(
        0,
        ge=0,
        description="After the refining updates, this many updates of one likelihood kind settle the new place's level without the drop test; "
        "then their average (as ``average`` says) is compared with the slow average tracked before the detection (same kind): "
        "more than verify_tolerance under it is a wrong place, and the filter relocalizes again (0: no check, the test resumes at once).",
    )
    verify_tolerance: float = Field(6.0, ge=0, description="Nats the settled level may lie under the level tracked before the detection.")
    refine_fraction: float = Field(0.3, ge=0, le=1, description="Share of the particles re-drawn around the posterior by each refining update.")
    refine_scale: float = Field(
        1.0, gt=0, description="Refining draws: N(estimate, refine_scale² Σ + floor²), Σ the cloud's weighted covariance (tangent space)."
    )
    refine_min_position: float = Field(0.005, ge=0, description="Floor of the refining draws' position standard deviation per axis, map units.")
    refine_min_rotation_deg: float = Field(0.5, ge=0, description="Floor of the refining draws' rotation standard deviation per axis, degrees.")
    refine_pivot_depth: float = Field(
        0.0, ge=0, description="Refining draws: distance (map units) ahead of the camera of the point their pivot swings turn about."
    )
    refine_pivot_sigma_deg: float = Field(
        0.0,
        ge=0,
        description="Refining draws: σ (degrees) of swings about the camera's x and y axes through the point refine_pivot_depth ahead "
        "(locnerf.filter.motion.PivotNoise), added to the Gaussian: the turn and the sideways shift that keep the view, along which "
        "a relocalized cloud closes slowest (0: none).",
    )

    search: CrossEntropyConfig | None = Field(
        None,
        description="After the refining updates (a relocalization's or the keyframe start's), search the estimate by the cross-entropy "
        "method on the next search_updates updates' own likelihood (their pixels, reference and depth points; the worker of the update "
        "runs it) and move the cloud by the offset of the best pose found (None: off). Closes the last centimetres a relocalized cloud "
        "would otherwise close at the prediction noise's pace.",
    )
    search_updates: int = Field(1, ge=1, description="Updates, one after the other, that each carry a search once the refining updates end.")
    search_max_spread: float = Field(
        0.05,
        gt=0,
        description="A due search waits for a cloud whose largest per-axis weighted position spread is at most this (map units): "
        "the search starts from the cloud's covariance, and one from a cloud still closing in reached other places.",
    )
    search_min_gain: float = Field(0.0, ge=0, description="Nats the found pose must score above the estimate on the search's pixels before the cloud is moved.")

    @model_validator(mode="after")
    def _consistent(self) -> RecoveryConfig:
        if self.place_check_views > 0 and self.keyframe_share == 0:
            raise ValueError(f"place_check_views={self.place_check_views} with keyframe_share=0: expected keyframe_share > 0 (the image is matched only then)")
        if self.place_check_views > self.keyframe_count:
            raise ValueError(f"place_check_views={self.place_check_views} > keyframe_count={self.keyframe_count}: expected at most the keyframes matched")
        if self.alpha_fast <= self.alpha_slow:
            raise ValueError(f"alpha_fast={self.alpha_fast} <= alpha_slow={self.alpha_slow}: expected alpha_fast > alpha_slow")
        if self.local_max_radius < self.local_radius:
            raise ValueError(f"local_max_radius={self.local_max_radius} < local_radius={self.local_radius}: expected r_max >= r_0")
        return self


PlaceCheck = Callable[[], bool]
"""Whether the current update's image looks like the estimate's place (asked only of a low update)."""


def recognized_at(views: torch.Tensor, poses: torch.Tensor, max_position: float, max_rotation_deg: float) -> torch.Tensor:
    """(J, I) bool: whether any of the keyframe poses ``views[j]`` (J, V, 4, 4), those most like image j, lies within
    ``max_position`` (map units) and ``max_rotation_deg`` of pose i (I, 4, 4). False where V = 0."""
    views, poses = views.double().cpu()[:, :, None], poses.double().cpu()[None, None]
    near = (translation_error(views, poses) <= max_position) & (rotation_error_deg(views, poses) <= max_rotation_deg)
    return near.any(dim=1)


def place_recognized(candidates: torch.Tensor, estimate: torch.Tensor, max_position: float, max_rotation_deg: float) -> bool:
    """Whether any of the keyframe poses ``candidates`` (C, 4, 4), those most like an image, lies within
    ``max_position`` (map units) and ``max_rotation_deg`` of ``estimate`` (4, 4): the image still looks
    like where the filter believes it is (:func:`recognized_at` for one image and one pose)."""
    return bool(recognized_at(candidates[None], estimate[None], max_position, max_rotation_deg)[0, 0])


@dataclass(frozen=True)
class InjectionPlan:
    """How many fresh particles one update injects, and how far from the estimate the local ones go.

    Attributes:
        fraction: share of the resampled particles to replace, in [0, 1].
        local_radius: half side of the position cube around the estimate, map units.
        local_yaw: bound of the yaw offset from the estimate, radians.
        around_estimate: a refining update: every fresh particle is drawn from the cloud's own Gaussian
            (``refine_*`` of :class:`RecoveryConfig`), none around keyframes, locally or uniformly.
    """

    fraction: float
    local_radius: float
    local_yaw: float
    around_estimate: bool = False


def _log_ema(log_average: float | None, log_value: float, rate: float, of_logs: bool = False) -> float:
    """log((1 − α)·avg + α·value) from logs, or with ``of_logs`` (1 − α)·log avg + α·log value; the
    first value initialises the average."""
    if log_average is None:
        return log_value
    if of_logs:
        return log_average + rate * (log_value - log_average)
    a, b = math.log1p(-rate) + log_average if rate < 1 else -math.inf, math.log(rate) + log_value
    high = max(a, b)
    return high + math.log(math.exp(a - high) + math.exp(b - high))


class RecoveryMonitor:
    """The slow and fast log-likelihood averages of augmented MCL, the current injection streak and,
    after a kidnapping is detected, the refining updates still to come (``relocalize_updates``) and
    the verification of the new place (``verify_updates``).

    Likelihoods of different kinds (rendered, re-projected: they measure different pixels) are not
    compared: a change of kind starts the averages afresh. The slow average last tracked before a
    detection is kept per kind, as the level a right place should reach again."""

    def __init__(self, config: RecoveryConfig) -> None:
        self.config = config
        self.log_slow: float | None = None
        self.log_fast: float | None = None
        self.streak = 0
        self.low = 0
        self.refining = 0
        self.fired = 0  # injection streaks started since construction (not forgotten by reset)
        self.kind: object = None
        self.tracked: dict[object, float] = {}  # per likelihood kind: the slow average before the low updates
        self.verifying = False
        self.settling: list[float] = []  # the verification's log-likelihoods so far (one kind)
        self.searches = 0  # updates still to carry a search (config.search) since the last refining update
        self.drops_in_place = 0  # low updates not counted: the image looked like the estimate's place (config.place_check_views)

    def reset(self) -> None:
        """Forget the history (after a re-initialisation)."""
        self.forget_level()
        self.streak = 0
        self.refining = 0
        self.tracked = {}
        self.verifying = False
        self.searches = 0

    @property
    def search_due(self) -> bool:
        """A search is owed (``config.search``, ``search_updates`` of them after the refining updates ended)."""
        return self.searches > 0

    def take_search(self) -> CrossEntropyConfig | None:
        """The search an update about to start should carry, counted off the searches due, or None."""
        if self.searches == 0:
            return None
        self.searches -= 1
        return self.config.search

    def forget_level(self) -> None:
        """Forget the likelihood averages, not a relocalization under way (the likelihood changed kind: rendered / re-projected)."""
        self.log_slow = self.log_fast = None
        self.low = 0
        self.settling = []

    def refine(self, updates: int) -> None:
        """Make the next ``updates`` updates refining ones, as after a detection (not counted as one):
        for a cloud just seeded around candidate views (:mod:`locnerf.filter.keyframe_start`)."""
        if updates < 0:
            raise ValueError(f"refining updates={updates}: expected a count >= 0")
        self.refining = updates

    def observe(self, log_mean_likelihood: float, kind: object = None, looks_in_place: PlaceCheck | None = None) -> InjectionPlan:
        """Feed one update's log mean likelihood of ``kind`` (any hashable label; a change forgets the
        averages); return what to inject after its resampling. ``looks_in_place``, asked only of a low
        update, says whether its image looks like the estimate's place (:func:`place_recognized`): such an
        update does not count toward a detection.

        While refining after a detection, the likelihood is not tested (the cloud is converging on
        the new place): each update re-draws ``refine_fraction`` around the posterior; after the last
        one the averages start afresh, first verified (:meth:`_verify`) when ``verify_updates`` > 0."""
        config = self.config
        if kind != self.kind:
            self.forget_level()
            self.kind = kind
        if self.refining > 0:
            self.refining -= 1
            if self.refining == 0:
                self.forget_level()
                self.verifying = config.verify_updates > 0
                self.searches = config.search_updates if config.search is not None else 0
            self.streak += 1
            return InjectionPlan(fraction=config.refine_fraction, local_radius=config.local_radius, local_yaw=0.0, around_estimate=True)
        if self.verifying:
            fraction = self._verify(log_mean_likelihood)
        else:
            fraction = self._test(log_mean_likelihood, looks_in_place)
        growth = config.local_growth**self.streak
        plan = InjectionPlan(
            fraction=fraction,
            local_radius=min(config.local_max_radius, config.local_radius * growth),
            local_yaw=math.radians(min(180.0, config.local_yaw_deg * growth)),
        )
        self.fired += int(fraction > 0 and self.streak == 0)
        self.streak = self.streak + 1 if fraction > 0 else 0
        self.refining = config.relocalize_updates if fraction > 0 else 0
        return plan

    def _test(self, log_mean_likelihood: float, looks_in_place: PlaceCheck | None) -> float:
        """The fraction to inject by the drop of the fast average under the slow one (augmented MCL,
        with the tolerance and the confirming updates; a low update whose image ``looks_in_place`` is
        not counted); remembers the slow level of a normal update."""
        config = self.config
        fraction = 0.0
        if math.isfinite(log_mean_likelihood):
            of_logs = config.average == "log"
            self.log_slow = _log_ema(self.log_slow, log_mean_likelihood, config.alpha_slow, of_logs)
            self.log_fast = _log_ema(self.log_fast, log_mean_likelihood, config.alpha_fast, of_logs)
            if config.enabled:
                ratio = math.exp(min(0.0, self.log_fast - self.log_slow + config.tolerance))
                fraction = min(config.max_fraction, max(0.0, 1.0 - ratio))
        if fraction > 0 and looks_in_place is not None and looks_in_place():
            self.drops_in_place += 1
            logger.info("recovery: %.2f nats under the slow level, but the image looks like the estimate's place: not counted", self.log_slow - self.log_fast)
            fraction = 0.0
        self.low = self.low + 1 if fraction > 0 else 0
        if self.low == 0 and self.log_slow is not None:
            self.tracked[self.kind] = self.log_slow
        if self.low < config.confirm_updates:
            fraction = 0.0
        if self.log_fast is not None and self.log_slow is not None:
            logger.debug("recovery: log-likelihood %.2f, fast %.2f, slow %.2f, fraction %.2f", log_mean_likelihood, self.log_fast, self.log_slow, fraction)
        return fraction

    def _verify(self, log_mean_likelihood: float) -> float:
        """Collect the new place's likelihoods; after ``verify_updates`` of them compare their level
        (log of the mean likelihood, or the mean log-likelihood with ``average = "log"``) with the one tracked before the detection: more than
        ``verify_tolerance`` under it re-fires (``max_fraction``), else the averages start from it."""
        config = self.config
        if math.isfinite(log_mean_likelihood):
            self.settling.append(log_mean_likelihood)
        if len(self.settling) < config.verify_updates:
            return 0.0
        values = torch.tensor(self.settling, dtype=torch.float64)
        level = float(values.mean()) if config.average == "log" else float(torch.logsumexp(values, 0)) - math.log(len(self.settling))
        before = self.tracked.get(self.kind)
        self.verifying = False
        self.settling = []
        wrong = before is not None and level < before - config.verify_tolerance
        logger.info(
            "recovery: the new place's level %.2f, %s before the detection: %s",
            level,
            "unknown" if before is None else f"{before:.2f}",
            "a wrong place, relocalizing again" if wrong else "kept",
        )
        if wrong:
            self.streak = 0  # a relocalization of its own (counted in ``fired``)
            return config.max_fraction
        self.log_slow, self.log_fast = level, float(values[-1])
        return 0.0


@dataclass(frozen=True)
class KeyframeCandidates:
    """Keyframes that look like the current image: where a lost robot probably is.

    Attributes:
        poses: (C, 4, 4) float64 keyframe poses, best match first.
        spacing: the keyframes' typical spacing, map units (scales the draws around them).
    """

    poses: torch.Tensor
    spacing: float


def keyframe_particles(candidates: KeyframeCandidates, count: int, position_sigma: float, rotation_sigma: float, generator: torch.Generator) -> torch.Tensor:
    """``count`` poses ``K_j · Exp(δ)`` spread equally over the candidates ``K_j`` (best first for
    the remainder), δ ~ N(0, diag(rotation_sigma² I₃, position_sigma² I₃)) in the keyframe's frame.

    Returns:
        (count, 4, 4) float64 on the CPU.
    """
    poses = candidates.poses.double().cpu()
    which = torch.arange(count) % poses.shape[0]
    sigma = torch.tensor([rotation_sigma] * 3 + [position_sigma] * 3, dtype=torch.float64)
    return poses[which] @ se3_exp(torch.randn(count, 6, dtype=torch.float64, generator=generator) * sigma)


def keyframe_orbit_particles(
    candidates: KeyframeCandidates,
    count: int,
    depth: float,
    arc_sigma: float,
    distance_sigma: float,
    rotation_sigma: float,
    up: tuple[float, float, float],
    generator: torch.Generator,
) -> torch.Tensor:
    """``count`` poses circling the point ``p_j = K_j (0, 0, −depth)`` that each candidate ``K_j``
    looks at (equally over the candidates, best first for the remainder), level as the keyframe is.

    Each draw is ``A(α) · K_j · P E(β) P⁻¹ · Exp(δ)``: ``A(α)`` turns by the azimuth α about the
    world ``up`` axis through ``p_j`` (a turn about the vertical keeps a level camera level),
    ``P E(β) P⁻¹`` by the elevation β about the keyframe's x axis through ``p_j`` (``P`` the
    translation to it), with α, β ~ N(0, (arc_sigma / depth)²); δ ~ N(0, diag(rotation_sigma² I₃,
    0, 0, distance_sigma²)) adds a small turn and a change of distance along the viewing axis.

    Why: on an object-centred map (the lego orbit: keyframes and the test orbit all look at the
    object from 4.03 units) the truth differs from the best-matching keyframe by a move along the
    sphere around the object, about half a unit, with the rotation that keeps the object in view
    and up to 7° of relative roll. Gaussian draws in 6-D hardly ever land near it; these do
    (docs/RESULTS.md, "Live lego orbit: orbit draws around keyframes").

    Returns:
        (count, 4, 4) float64 on the CPU.
    """
    if depth <= 0:
        raise ValueError(f"orbit depth={depth}: expected a distance > 0 (map units)")
    axis = torch.tensor(up, dtype=torch.float64)
    if not bool(torch.isfinite(axis).all()) or float(axis.norm()) == 0.0:
        raise ValueError(f"up={up}: expected a finite non-zero axis")
    keyframes = candidates.poses.double().cpu()[torch.arange(count) % candidates.poses.shape[0]]
    angles = torch.randn(count, 2, dtype=torch.float64, generator=generator) * (arc_sigma / depth)
    delta = torch.randn(count, 6, dtype=torch.float64, generator=generator) * torch.tensor(
        [rotation_sigma] * 3 + [0.0, 0.0, distance_sigma], dtype=torch.float64
    )
    elevation = torch.zeros(count, 6, dtype=torch.float64)  # P E(β) P⁻¹ = Exp(β, 0, 0, 0, −depth β, 0)
    elevation[:, 0] = angles[:, 1]
    elevation[:, 4] = -depth * angles[:, 1]
    centre = keyframes[:, :3, :3] @ torch.tensor([0.0, 0.0, -depth], dtype=torch.float64) + keyframes[:, :3, 3]
    turn = rotation_about_axis(axis / axis.norm(), angles[:, 0])
    azimuth = make_pose(turn, centre - (turn @ centre[:, :, None])[:, :, 0])
    return azimuth @ keyframes @ se3_exp(elevation) @ se3_exp(delta)


def keyframe_draws(
    candidates: KeyframeCandidates, count: int, config: RecoveryConfig, up: tuple[float, float, float], generator: torch.Generator
) -> torch.Tensor:
    """``count`` fresh poses around ``candidates`` with the spreads of ``config``: orbit draws
    (:func:`keyframe_orbit_particles`) when ``keyframe_orbit_depth`` > 0, else Gaussian ones
    (:func:`keyframe_particles`); position spreads in keyframe spacings, or in map units when
    ``keyframe_position_sigma_map`` is set. Returns (count, 4, 4) float64."""
    sigma = config.keyframe_position_sigma_map or config.keyframe_position_sigma * candidates.spacing
    rotation = math.radians(config.keyframe_rotation_sigma_deg)
    if config.keyframe_orbit_depth > 0:
        depth = config.keyframe_orbit_depth
        return keyframe_orbit_particles(candidates, count, depth, sigma, config.keyframe_orbit_distance_sigma, rotation, up, generator)
    return keyframe_particles(candidates, count, sigma, rotation, generator)


def injection_poses(
    plan: InjectionPlan,
    count: int,
    config: RecoveryConfig,
    estimate: torch.Tensor | ParticleEstimate,
    bounds: torch.Tensor,
    up: tuple[float, float, float],
    generator: torch.Generator,
    candidates: KeyframeCandidates | None = None,
) -> torch.Tensor:
    """Fresh particle poses: around the candidate keyframes, around the estimate, and uniform; or,
    for a refining plan, from the cloud's own Gaussian (:func:`refining_draws`).

    ``round(count · keyframe_share)`` go around the candidates (none without candidates); of the
    rest, ``round(rest · local_share)`` around the estimate and the others uniformly.

    Args:
        plan: radius and yaw bound of the local draws, or ``around_estimate``.
        config: the shares and spreads.
        estimate: (4, 4) current estimate, or the :class:`ParticleEstimate` (its pose and covariance:
            a refining plan needs the covariance); its position centres the local cube, its rotation gives
            the local and uniform particles' roll and pitch (and the local particles' yaw before
            the offset).
        bounds: (2, 3) search region [min, max] for the uniform draws.
        up: world axis opposite to gravity (the yaw axis).
        candidates: keyframes matching the image, or None.
    Returns:
        (count, 4, 4) float64 on the CPU: keyframe draws, then local, then uniform.
    """
    if plan.around_estimate:
        if not isinstance(estimate, ParticleEstimate):
            raise ValueError("a refining injection draws from the cloud's covariance: pass the ParticleEstimate, not its pose")
        return refining_draws(estimate, count, config, generator)
    if isinstance(estimate, ParticleEstimate):
        estimate = estimate.pose
    by_keyframe = round(count * config.keyframe_share) if candidates is not None else 0
    local = round((count - by_keyframe) * config.local_share)
    estimate = estimate.double().cpu()
    parts = [global_particles(estimate, local, generator, plan.local_radius, up, max_yaw=plan.local_yaw)]
    parts.append(uniform_particles(bounds, count - by_keyframe - local, generator, estimate[:3, :3], up))
    if by_keyframe > 0:
        parts.insert(0, keyframe_draws(candidates, by_keyframe, config, up, generator))
    return torch.cat(parts)


def refining_draws(estimate: ParticleEstimate, count: int, config: RecoveryConfig, generator: torch.Generator) -> torch.Tensor:
    """``count`` poses ``estimate.pose · Exp(δ)``, δ ~ N(0, refine_scale² Σ + diag(floor²) + Π), Σ the
    cloud's covariance (6, 6, rotation first), the floors ``refine_min_rotation_deg`` and
    ``refine_min_position`` per axis, and Π the covariance of the pivot swings ``refine_pivot_*`` (none by
    default; :meth:`locnerf.filter.motion.PivotNoise.covariance`): a Gaussian fitted to the posterior, as in a regularised particle
    filter, so that after a re-seed the cloud closes in on the new place over a few updates (the draws
    shrink with the posterior: coarse to fine) instead of waiting for the prediction noise.

    Returns:
        (count, 4, 4) float64 on the CPU.
    """
    covariance = estimate.covariance.double().cpu()
    floor = torch.tensor([math.radians(config.refine_min_rotation_deg)] * 3 + [config.refine_min_position] * 3, dtype=torch.float64)
    covariance = config.refine_scale**2 * 0.5 * (covariance + covariance.T) + torch.diag(floor**2)
    if config.refine_pivot_sigma_deg > 0:
        covariance = covariance + PivotNoise.equal_swings(config.refine_pivot_depth, config.refine_pivot_sigma_deg).covariance()
    return gaussian_particles(estimate.pose.double().cpu(), covariance, count, generator)
