"""The Monte Carlo localizer: predict, snapshot, merge (and a synchronous update), no I/O, no clock.

Delayed updates (design section 3): :meth:`Localizer.snapshot` records the generation, ids and
poses that an update will be computed on; :meth:`Localizer.merge` later gives each current particle
the log-likelihood of its ancestor in that generation, then normalises, resamples and anneals. A
result whose snapshot predates a re-initialisation (an older ``epoch``) is stale: refused and
counted. The localizer is used from one thread only.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from locnerf.filter import initialization
from locnerf.filter.ancestor_scores import best_weighed_log_likelihood, current_log_likelihoods
from locnerf.filter.annealing import AnnealingStage, noise_scale, particle_count, stage_for_spread
from locnerf.filter.cloud_search import PoseSearch, cloud_within, pose_search, search_move, with_own_pixels
from locnerf.filter.convergence_protection import redrawn_positions
from locnerf.filter.depth_measurement import (
    DepthObservation,
    SurfaceDistanceLookup,
)
from locnerf.filter.estimate import ParticleEstimate, estimate_from_particles
from locnerf.filter.final_search import FinalSearchResult, cross_entropy_search
from locnerf.filter.keyframe_start import seed_start
from locnerf.filter.keyframes import KeyframeIndex
from locnerf.filter.kld import kld_resample
from locnerf.filter.lineage import NO_ANCESTOR, Lineage
from locnerf.filter.localizer_config import LocalizerConfig, SearchRegion
from locnerf.filter.measurement import (
    RenderRays,
)
from locnerf.filter.motion import PivotNoise, propagate_poses
from locnerf.filter.particles import ParticleSet, normalise_log_weights, weighted_position_spread
from locnerf.filter.recovery import (
    InjectionPlan,
    KeyframeCandidates,
    PlaceCheck,
    RecoveryMonitor,
    injection_poses,
    place_recognized,
)
from locnerf.filter.resampling import RESAMPLERS, effective_sample_size
from locnerf.filter.tempering import tempered, tempering_exponent
from locnerf.filter.update_likelihood import search_likelihood, update_likelihood
from locnerf.filter.warp import SurfaceRays, warp_reference_pose
from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

CandidateSource = Callable[[], KeyframeCandidates | None]


@dataclass(frozen=True)
class UpdateSnapshot:
    """What an update is computed on: ``poses`` (N, 4, 4) and ``ids`` (N,) of ``generation``."""

    epoch: int
    generation: int
    ids: torch.Tensor
    poses: torch.Tensor


class MergeOutcome(enum.StrEnum):
    """What merging one update result did (the values name the localizer's counters)."""

    MERGED = "merged"
    """Weighed, resampled and annealed."""
    STALE = "stale"
    """Snapshot from an older epoch or an untraceable generation: nothing changed."""
    DEGENERATE = "degenerate"
    """No current particle got a finite likelihood: weights and particles left unchanged, no resampling."""


@dataclass(frozen=True)
class MergeReport:
    """Outcome of merging one update result, and the particles after it."""

    outcome: MergeOutcome
    generation: int
    effective_sample_size: float
    """Kish's ``1 / Σ w²`` of the weights the update gave, before resampling (after it they are uniform);
    of the unchanged weights when nothing was merged."""
    particle_count: int
    stage: AnnealingStage
    injected: int = 0
    rays: int = 0
    """Rays rendered for the update (set by :meth:`Localizer.update`; 0 for merged results of others)."""


class Localizer:
    """The particle filter of Loc-NeRF with delayed-update merging.

    Args:
        config: filter parameters.
        generator: CPU ``torch.Generator`` for every random draw.
        device: where particle poses live and rendering happens.
        dtype: dtype of particle poses (float32 default; float64 for oracles).
        region: search region for recovery injections (required when recovery is enabled).
        keyframes: the map's keyframes; when a merge injects recovery particles, the update's image
            is matched against them and a share (``recovery.keyframe_share``) of the fresh
            particles is drawn around the best matches; after a uniform or global start, the first
            image re-draws a share (``keyframe_start.share``) of the particles likewise.
    """

    def __init__(
        self,
        config: LocalizerConfig,
        generator: torch.Generator,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        region: SearchRegion | None = None,
        keyframes: KeyframeIndex | None = None,
    ) -> None:
        if config.recovery.enabled and region is None:
            raise ValueError("recovery is enabled but no search region was given: pass region=SearchRegion(...)")
        self.config = config
        self.generator = generator
        self.device = torch.device(device)
        self.dtype = dtype
        self.region = region
        self.keyframes = keyframes
        self._warned_camera = self._warned_no_depth = False
        self.epoch = 0
        self.stage = AnnealingStage.COARSE
        self.particles: ParticleSet | None = None
        self._lineage = Lineage(config.lineage_depth)
        self._recovery = RecoveryMonitor(config.recovery)
        self._next_id = 0
        self._keyframe_start_pending = False
        self._start_up: tuple[float, float, float] = (0.0, 1.0, 0.0)
        self._update_ess: float | None = None
        self._moved = torch.eye(4, dtype=torch.float64)  # product of the searches' moves so far (world frame)
        counted = ("merged", "stale", "degenerate", "injected", "tempered", "recoveries", "searches", "searches_moved", "drops_in_place")
        self.counters = dict.fromkeys(counted, 0)

    # ----------------------------------------------------------------- initialisation
    def initialize(self, poses: torch.Tensor) -> None:
        """Start a new epoch from explicit particle poses (N, 4, 4), equally weighted."""
        validate_poses(poses, name="initial particle poses")
        if poses.ndim != 3 or poses.shape[0] == 0:
            raise ValueError(f"initial particle poses: expected shape (N>=1, 4, 4), got {tuple(poses.shape)}")
        self.particles = ParticleSet.from_poses(poses.to(self.device, self.dtype), first_id=self._next_id)
        self._next_id += self.particles.count
        self.epoch += 1
        self.stage = AnnealingStage.COARSE
        self._lineage.clear()
        self._recovery.reset()
        self._keyframe_start_pending = False
        self._update_ess = None

    def initialize_inerf(self, center: torch.Tensor, translation_half_width: float = 0.1, max_angle_deg: float = 40.0) -> None:
        """Particles spread by the iNeRF protocol around ``center`` (4, 4)."""
        self.initialize(initialization.inerf_particles(center, self.config.particles, self.generator, translation_half_width, max_angle_deg))

    def initialize_global(self, center: torch.Tensor, half_width: float = 1.0, up: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> None:
        """The paper's global protocol: cube of side 2·half_width around ``center``, yaw uniform.

        With ``keyframe_start.share`` > 0 and keyframes, the next image seeds part of them
        (:meth:`seed_from_image`), as after a uniform start."""
        self.initialize(initialization.global_particles(center, self.config.particles, self.generator, half_width, up))
        self._arm_keyframe_start(up)

    def initialize_gaussian(self, mean: torch.Tensor, covariance: torch.Tensor) -> None:
        """Particles ``mean · Exp(δ)``, δ ~ N(0, covariance) (6×6, rotation first)."""
        self.initialize(initialization.gaussian_particles(mean, covariance, self.config.particles, self.generator))

    def initialize_uniform(self, region: SearchRegion, tilt: torch.Tensor | None = None) -> None:
        """Positions uniform in the region, yaw uniform about its up axis, fixed tilt (roll/pitch): ``tilt``
        (3, 3), or level when None (the camera's y axis along ``region.up``, looking horizontally).

        With ``keyframe_start.share`` > 0 and keyframes, the next image seeds part of them
        (:meth:`seed_from_image`)."""
        self.initialize(initialization.uniform_particles(region.bounds(), self.config.particles, self.generator, tilt, region.up))
        self._arm_keyframe_start(region.up)

    def _arm_keyframe_start(self, up: tuple[float, float, float]) -> None:
        """Let the next image seed the start around matching keyframes, when configured and possible."""
        self._start_up = up
        self._keyframe_start_pending = self.config.keyframe_start.share > 0 and self.keyframes is not None

    def seed_from_image(self, image: torch.Tensor, intrinsics: PinholeIntrinsics) -> int:
        """After a uniform or global start, re-draw ``keyframe_start.share`` of the particles around the
        keyframes most like ``image`` (H, W, 3) in [0, 1] (:mod:`locnerf.filter.keyframe_start`);
        once per start, before its first snapshot. Returns how many particles were re-drawn."""
        if not self._keyframe_start_pending:
            return 0
        self._keyframe_start_pending = False
        candidates = self._matching_keyframes(image, intrinsics)
        if candidates is None:
            return 0
        particles = self._require_particles()
        particles.poses = seed_start(particles.poses, candidates, self.config.keyframe_start, self.config.recovery, self.generator, self._start_up)
        self._recovery.refine(self.config.keyframe_start.refine_updates if self.config.recovery.enabled else 0)  # recovery's refine_* draws
        seeded = round(self.config.keyframe_start.share * particles.count)
        logger.info("keyframe start: %d of %d particles re-drawn around %d matching keyframes", seeded, particles.count, len(candidates.poses))
        return seeded

    def _require_particles(self) -> ParticleSet:
        if self.particles is None:
            raise RuntimeError("the localizer has no particles yet: call one of the initialize_* methods first")
        return self.particles

    # ----------------------------------------------------------------- prediction
    def noise_sigma(self, periods: float = 1.0) -> torch.Tensor:
        """(6,) current prediction-noise standard deviations (annealed) over ``periods`` odometry periods: δ is a random
        walk whose variance grows with the time bridged, so σ scales by √periods (at least one period's noise)."""
        return self.config.motion.sigma_vector(noise_scale(self.stage, self.config.annealing) * math.sqrt(max(periods, 1.0)))

    def noise_pivot(self, periods: float = 1.0) -> PivotNoise | None:
        """The current pivot noise (annealed like δ, widened over ``periods`` like :meth:`noise_sigma`), or None."""
        return self.config.motion.pivot_noise(noise_scale(self.stage, self.config.annealing) * math.sqrt(max(periods, 1.0)))

    def predict(self, odometry: torch.Tensor | None = None, periods: float = 1.0) -> None:
        """Eq. 4 for every particle: move by the odometry increment ``T_prev_curr`` (4, 4), add ``periods`` periods' noise."""
        particles = self._require_particles()
        if odometry is not None:
            validate_poses(odometry, name="odometry increment")
            if odometry.ndim != 2:
                raise ValueError(f"odometry increment: expected shape (4, 4), got {tuple(odometry.shape)}")
        if not math.isfinite(periods) or periods <= 0:
            raise ValueError(f"prediction over {periods} odometry periods: expected a positive finite number")
        particles.poses = propagate_poses(particles.poses, odometry, self.noise_sigma(periods), self.generator, self.noise_pivot(periods))

    # ----------------------------------------------------------------- delayed update
    def _protect_convergence(self, particles: ParticleSet) -> None:
        """Re-draw ``convergence_protection.count`` particle positions uniformly around the weighted mean.

        A re-drawn particle is a new hypothesis, so it becomes a new particle: the re-drawing starts a
        generation in which the others keep their ids (each its own parent) and the re-drawn ones get
        fresh ids with no ancestor. An update still in flight on an older snapshot then gives them the
        median likelihood, never the one computed for the pose they replaced (design section 3). Until
        an update weighs them they are, like recovery's injections, left out of the estimate
        (``parent_ids`` is :data:`NO_ANCESTOR`)."""
        redrawn = redrawn_positions(particles.positions, particles.weights, self.config.convergence_protection, self.generator)
        if redrawn is None:
            return
        chosen, positions = redrawn
        particles.poses[chosen, :3, 3] = positions
        ids, lineage_parents, parent_ids = particles.ids.clone(), particles.ids.clone(), particles.parent_ids.clone()
        ids[chosen] = self._fresh_ids(len(chosen))
        lineage_parents[chosen] = NO_ANCESTOR
        parent_ids[chosen] = NO_ANCESTOR
        self._start_generation(particles, ids, lineage_parents)
        particles.parent_ids = parent_ids

    def _fresh_ids(self, count: int) -> torch.Tensor:
        """(count,) int64 particle ids never issued before."""
        ids = torch.arange(self._next_id, self._next_id + count, dtype=torch.int64, device=self.device)
        self._next_id += count
        return ids

    def _start_generation(self, particles: ParticleSet, ids: torch.Tensor, lineage_parents: torch.Tensor) -> None:
        """Give ``particles`` the ids (N,) of a new generation whose parents (N,) in the previous one the
        lineage records (:data:`NO_ANCESTOR` for particles that descend from none)."""
        particles.generation += 1
        self._lineage.record(particles.generation, ids, lineage_parents)
        particles.ids = ids

    def snapshot(self, carry: torch.Tensor | None = None) -> UpdateSnapshot:
        """Freeze the particles for an update (after convergence protection).

        Args:
            carry: (4, 4) increment from the last odometry stamp to the image stamp, applied
                without noise to the snapshot's poses only; None if they coincide.
        """
        particles = self._require_particles()
        self._protect_convergence(particles)
        poses = particles.poses.clone()
        if carry is not None:
            validate_poses(carry, name="carry increment")
            poses = poses @ carry.to(self.device, self.dtype)
        return UpdateSnapshot(self.epoch, particles.generation, particles.ids.clone(), poses)

    def _record(self, outcome: MergeOutcome, injected: int = 0, effective: float | None = None) -> MergeReport:
        """Count ``outcome`` and describe the particles after it (``effective``: the update's ESS before
        resampling; that of the current weights when None)."""
        particles = self._require_particles()
        self.counters[outcome.value] += 1
        return MergeReport(
            outcome=outcome,
            generation=particles.generation,
            effective_sample_size=effective_sample_size(particles.weights) if effective is None else effective,
            particle_count=particles.count,
            stage=self.stage,
            injected=injected,
        )

    def merge(
        self,
        epoch: int,
        generation: int,
        ids: torch.Tensor,
        log_likelihoods: torch.Tensor,
        find_candidates: CandidateSource | None = None,
        warped: bool = False,
    ) -> MergeReport:
        """Merge an update computed on snapshot ``(epoch, generation)``.

        Args:
            ids: (K,) int64 particle ids of the snapshot.
            log_likelihoods: (K,) log-likelihoods of those particles; −inf (a failed render, as
                workers report it), NaN and +inf count as zero likelihood. When no current particle
                gets a finite likelihood the update is DEGENERATE: nothing changes, recovery is not fed.
            find_candidates: called, only when this merge injects recovery particles or checks a low update's
                place (``recovery.place_check_views``), for the keyframes that match the update's image
                (e.g. ``lambda: localizer.keyframe_candidates(image, intrinsics)``); at most once.
            warped: the likelihoods come from re-projection (:mod:`locnerf.filter.warp`), not from
                renders. The two measure different pixels, so their levels differ: when the kind
                changes, the recovery monitor forgets its averages instead of reading the step as a
                kidnapping (or as a recovery).
        Returns:
            What happened (see :class:`MergeReport`).
        """
        particles = self._require_particles()
        ids = torch.as_tensor(ids, dtype=torch.int64).cpu()
        log_likelihoods = torch.as_tensor(log_likelihoods, dtype=torch.float64).cpu()
        if ids.ndim != 1 or log_likelihoods.shape != ids.shape:
            raise ValueError(
                f"update result: expected ids (K,) and log_likelihoods (K,) of equal length, got {tuple(ids.shape)} and {tuple(log_likelihoods.shape)}"
            )
        if epoch != self.epoch:
            logger.info("dropping an update from epoch %d (current epoch %d)", epoch, self.epoch)
            return self._record(MergeOutcome.STALE)
        try:
            ancestors = self._lineage.ancestors(particles.ids, particles.generation, generation)
        except ValueError as error:
            logger.info("dropping an update: %s", error)
            return self._record(MergeOutcome.STALE)

        per_particle = current_log_likelihoods(ids, log_likelihoods, ancestors, particles.poses, self.config.borrow_reach)
        log_weights = particles.log_weights.double().cpu()
        if not bool(torch.isfinite(log_weights + per_particle).any()):
            logger.warning("degenerate update (no current particle has a finite likelihood): particles and weights kept unchanged")
            return self._record(MergeOutcome.DEGENERATE)

        combined = log_weights + self._temper(log_weights, per_particle)
        weighed = normalise_log_weights(combined).to(self.device, self.dtype)
        if find_candidates is not None:
            find_candidates = functools.cache(find_candidates)  # the place check and the injection match the image once
        looks_in_place = self._place_check(particles, weighed, find_candidates)
        plan = self._recovery.observe(best_weighed_log_likelihood(particles.parent_ids, per_particle), "warped" if warped else "rendered", looks_in_place)
        self.counters["recoveries"] = self._recovery.fired  # injection streaks started: times the filter found itself lost
        self.counters["drops_in_place"] = self._recovery.drops_in_place
        injected = self._resample(particles, weighed, plan, find_candidates)
        self._update_ess = effective_sample_size(torch.exp(weighed).double())
        return self._record(MergeOutcome.MERGED, injected, self._update_ess)

    def _place_check(self, particles: ParticleSet, log_weights: torch.Tensor, find_candidates: CandidateSource | None) -> PlaceCheck | None:
        """The recovery monitor's question for a low update (``recovery.place_check_views`` > 0): do any of the
        keyframes most like its image lie near the estimate the update's normalised ``log_weights`` (N,) give?
        None when the check is off or the image cannot be matched."""
        recovery = self.config.recovery
        if recovery.place_check_views == 0 or find_candidates is None:
            return None

        def looks_in_place() -> bool:
            candidates = find_candidates()
            if candidates is None:
                return False
            estimate = estimate_from_particles(dataclasses.replace(particles, log_weights=log_weights), self.stage).pose
            views = candidates.poses[: recovery.place_check_views]
            return place_recognized(views, estimate, recovery.place_check_position, recovery.place_check_rotation_deg)

        return looks_in_place

    def _temper(self, log_weights: torch.Tensor, per_particle: torch.Tensor) -> torch.Tensor:
        """The update's log-likelihoods (N,) times the tempering exponent β (:mod:`locnerf.filter.tempering`)."""
        tempering = self.config.tempering
        if tempering.min_ess_fraction is None or (tempering.coarse_only and self.stage != AnnealingStage.COARSE):
            return per_particle
        beta = tempering_exponent(log_weights, per_particle, tempering.min_ess_fraction)
        if beta < 1.0:
            self.counters["tempered"] += 1
            logger.debug("update tempered by beta=%.3g", beta)
        return tempered(per_particle, beta)

    def _resample(self, particles: ParticleSet, log_weights: torch.Tensor, plan: InjectionPlan, find_candidates: CandidateSource | None) -> int:
        """Resample ``particles`` by the update's normalised ``log_weights`` (N,) to the stage's particle count,
        inject recovery particles by ``plan``, start a new generation. The particles and the stage change
        only once the draws have succeeded."""
        weights = torch.exp(log_weights).double()
        # A filter that injects believes it is lost: back to the COARSE stage (full noise and count).
        spread = math.inf if plan.fraction > 0 else weighted_position_spread(particles.positions.double(), weights)
        stage = stage_for_spread(spread, self.config.annealing)
        resampler = RESAMPLERS[self.config.resampler]
        if self.config.kld.enabled and (plan.fraction == 0 or plan.around_estimate):  # refining: the count follows the closing cloud
            indices = kld_resample(weights, particles.poses, self.config.kld, self.config.particles, resampler, self.generator).to(self.device)
            target = int(indices.shape[0])
        else:  # a filter that injects is lost: KLD-sampling then keeps the full count
            target = self.config.particles if self.config.kld.enabled else particle_count(stage, self.config.particles, self.config.annealing)
            indices = resampler(weights, target, self.generator).to(self.device)
        poses = particles.poses[indices]
        parents = particles.ids[indices]
        injected = int(round(plan.fraction * target))
        if injected > 0:
            estimate = estimate_from_particles(dataclasses.replace(particles, log_weights=log_weights), stage)
            candidates = find_candidates() if find_candidates is not None else None
            fresh = injection_poses(plan, injected, self.config.recovery, estimate, self.region.bounds(), self.region.up, self.generator, candidates)
            replaced = torch.randperm(target, generator=self.generator)[:injected].to(self.device)
            poses[replaced] = fresh.to(self.device, self.dtype)
            parents[replaced] = NO_ANCESTOR
            self.counters["injected"] += injected
        self.stage = stage
        self._start_generation(particles, self._fresh_ids(target), parents)
        particles.poses = poses
        particles.parent_ids = parents
        particles.log_weights = torch.full((target,), -float(torch.log(torch.tensor(float(target)))), dtype=self.dtype, device=self.device)
        return injected

    # ----------------------------------------------------------------- synchronous use
    def update(
        self,
        image: torch.Tensor,
        intrinsics: PinholeIntrinsics,
        render_rays: RenderRays,
        render_surface: SurfaceRays | None = None,
        depth: DepthObservation | None = None,
        surface_distance: SurfaceDistanceLookup | None = None,
    ) -> MergeReport:
        """One complete update on an image (H, W, 3) in [0, 1]: the keyframe start when one is
        pending, snapshot, render (``measurement.pixels_for`` the particle count, or by re-projection
        of one reference render when ``measurement.warp`` is set and the cloud is tight: ``render_surface``
        is then needed, see :mod:`locnerf.filter.warp`), merge.

        With ``measurement.depth`` set and a ``depth`` image of the frame, the depth term
        (:mod:`locnerf.filter.depth_measurement`) is added to the colour log-likelihoods: rendered
        from every particle (``render_surface`` needed), or re-projected from the reference render's
        surface points when the update warps; with ``measurement.depth.likelihood = "surface_distance"``,
        looked up in the map's ``surface_distance`` layer instead, on either path. Without ``measurement.depth``,
        ``depth`` is ignored; with it but no ``depth``, the update is colour only (warned once).

        When a search is due (``recovery.search``, after the refining updates), the estimate is searched on this
        update's likelihood (:func:`locnerf.filter.final_search.cross_entropy_search`) and the cloud moved after
        the merge (:meth:`move_by_search`); the report's rays include the search's."""
        if image.ndim != 3 or image.shape[-1] != 3:
            raise ValueError(f"image: expected shape (H, W, 3), got {tuple(image.shape)}")
        if (image.shape[0], image.shape[1]) != (intrinsics.height, intrinsics.width):
            raise ValueError(f"image size {image.shape[1]}×{image.shape[0]} does not match the intrinsics {intrinsics.width}×{intrinsics.height}")
        depth = self._depth_to_use(depth)
        config = self.config.measurement
        looked_up = depth is not None and config.depth.likelihood == "surface_distance"  # config.depth is set whenever depth is
        if looked_up and surface_distance is None:
            raise ValueError(
                "measurement.depth.likelihood is 'surface_distance' but the map has no surface-distance layer: build the map from depth images"
                " (or add one with `locnerf map add-surface-distance`), or use likelihood = 'rendered'"
            )
        if depth is not None and render_surface is None and not looked_up:
            raise ValueError(
                "measurement.depth is set but the map cannot place surfaces in its frame (an NDC or MLP map): leave [measurement.depth] unset for it"
            )
        self.seed_from_image(image, intrinsics)
        snap = self.snapshot()
        reference_pose = self.warp_reference(snap)
        if reference_pose is not None and render_surface is None:
            raise ValueError("measurement.warp is set but the map cannot place surfaces in its frame (an NDC or MLP map): leave warp unset for it")
        likelihood = update_likelihood(
            self.config.measurement,
            self.generator,
            self.device,
            snap.poses.shape[0],
            reference_pose,
            image,
            intrinsics,
            render_rays,
            render_surface,
            depth,
            surface_distance,
        )
        log_likelihoods = likelihood.score(snap.poses)
        rays = likelihood.fixed_rays + likelihood.rays_per_pose * snap.poses.shape[0]
        search = self.search_for(snap, image)
        found = None
        if search is not None:
            score, rays_per_pose = search_likelihood(likelihood, search.pixels, search.observed, self.config.measurement, intrinsics, render_rays, self.device)
            found = cross_entropy_search(
                search.mean,
                search.covariance,
                lambda poses: score(poses.to(self.device, self.dtype)).cpu(),
                search.config,
                torch.Generator().manual_seed(search.seed),
                rays_per_pose,
            )
            rays += found.rays
        report = self.merge(snap.epoch, snap.generation, snap.ids, log_likelihoods, lambda: self.keyframe_candidates(image, intrinsics), likelihood.warped)
        if found is not None and report.outcome is MergeOutcome.MERGED:
            self.move_by_search(search, found)
        return dataclasses.replace(report, rays=rays)

    def search_for(self, snap: UpdateSnapshot, image: torch.Tensor) -> PoseSearch | None:
        """The search an update of ``snap`` on ``image`` (H, W, 3) carries (``recovery.search`` after the refining updates),
        from the snapshot's weighted mean and covariance, with its own colour pixels of ``image`` when the search asks
        for them (``recovery.search.pixels``); None when none is due, or while the cloud is wider than
        ``recovery.search_max_spread`` (the search stays due)."""
        weights = self._require_particles().weights
        if not self._recovery.search_due or not cloud_within(snap.poses, weights, self.config.recovery.search_max_spread):
            return None
        seed = int(torch.randint(2**62, (1,), generator=self.generator))
        self.counters["searches"] += 1
        search = pose_search(self._recovery.take_search(), snap.poses, weights, seed, self._moved)
        return with_own_pixels(search, image, self.config.measurement, self.generator)

    def move_by_search(self, search: PoseSearch, found: FinalSearchResult) -> bool:
        """Move every particle so that the snapshot's mean lands on the pose the search found, when it scores
        ``recovery.search_min_gain`` nats or more above the mean (:func:`locnerf.filter.cloud_search.search_move`:
        a cloud already moved since the snapshot is not moved twice); returns whether it moved."""
        offset = search_move(search, found, self._moved, self.config.recovery.search_min_gain)
        if offset is None:
            return False
        particles = self._require_particles()
        particles.poses = offset.to(self.device, self.dtype) @ particles.poses
        self._moved = offset @ self._moved
        self.counters["searches_moved"] += 1
        return True

    def _depth_to_use(self, depth: DepthObservation | None) -> DepthObservation | None:
        """``depth`` when ``measurement.depth`` is set (warned once when the frame has none), else None."""
        if self.config.measurement.depth is None:
            return None
        if depth is None and not self._warned_no_depth:
            logger.warning("measurement.depth is set but the frame has no depth image: colour only for frames without depth")
            self._warned_no_depth = True
        return depth

    def warp_reference(self, snap: UpdateSnapshot) -> torch.Tensor | None:
        """The reference pose (4, 4) float64 of a re-projection update of ``snap`` (its weighted mean),
        or None: ``measurement.warp`` unset or the cloud too spread (:func:`warp_reference_pose`)."""
        warp = self.config.measurement.warp
        if warp is None:
            return None
        return warp_reference_pose(snap.poses, self._require_particles().weights, warp)

    def keyframe_candidates(self, image: torch.Tensor, intrinsics: PinholeIntrinsics) -> KeyframeCandidates | None:
        """The keyframes most like ``image`` (H, W, 3) seen with ``intrinsics``, when recovery draws
        around keyframes; None otherwise, or when the camera differs from the keyframes' (warned once)."""
        recovery = self.config.recovery
        if not recovery.enabled or recovery.keyframe_share == 0:
            return None
        return self._matching_keyframes(image, intrinsics)

    def _matching_keyframes(self, image: torch.Tensor, intrinsics: PinholeIntrinsics) -> KeyframeCandidates | None:
        """The ``recovery.keyframe_count`` keyframes most like ``image`` (H, W, 3); None without keyframes
        or when the camera differs from the keyframes' (warned once)."""
        if self.keyframes is None:
            return None
        if not self.keyframes.matches(intrinsics):
            if not self._warned_camera:
                logger.warning("image camera %s differs from the keyframes' %s: no particles are drawn around keyframes", intrinsics, self.keyframes.camera)
                self._warned_camera = True
            return None
        poses, _ = self.keyframes.query(image, self.config.recovery.keyframe_count)
        return KeyframeCandidates(poses, self.keyframes.spacing)

    def estimate(self) -> ParticleEstimate:
        """The current estimate (weighted mean pose, covariance, spread, ESS).

        Its effective sample size is that of the weights the last merged update gave before
        resampling (the weights are uniform after it): the filter's health, as a user watches it;
        the particle count after an initialisation.

        Particles injected by recovery at the last resampling or re-drawn by convergence protection
        since have not been weighed by any image yet: until the next update they are left out of
        pose, covariance and spread (otherwise uniform injections would drag the mean towards the
        middle of the search region).
        """
        particles = self._require_particles()
        weighed = particles.parent_ids != NO_ANCESTOR
        include = None if bool(weighed.all()) or not bool(weighed.any()) else weighed  # None: nothing injected, or a fresh initialisation
        return estimate_from_particles(particles, self.stage, include=include, effective_sample_size=self._update_ess)
