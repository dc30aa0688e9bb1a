"""The filter loop: owns the localizer; turns sensor, result and command messages into outputs.

Every ``handle_*`` method takes the payload bytes of one received message and returns the
messages to publish as ``(key, payload)`` pairs; :meth:`FilterLoop.tick` starts updates, expires
them and emits the periodic particle cloud and status. One thread calls all of them: the filter
state has a single owner (design section 3). Bad messages are counted by kind and dropped.

The particles change only through the loop's state machine (:mod:`.loop_state`), which applies
a deferred prediction before anything else touches them; frame conversions are in :mod:`.frames`,
the state file in :mod:`.persistence`.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Callable
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

from locnerf.field.protocol import MapNormalization
from locnerf.filter.estimate import ParticleEstimate
from locnerf.filter.localizer import Localizer, MergeOutcome
from locnerf.filter.localizer_config import SearchRegion
from locnerf.filter.measurement import observed_colours, sample_pixels_of_image
from locnerf.filter.measurement_config import MeasurementConfig
from locnerf.geometry.se3 import adjoint, pose_inverse
from locnerf.geometry.validation import InvalidPoseError, validate_pose_setting, validate_poses
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode, decode_rgbd, encode
from locnerf.messages.schemas import (
    DepthRequest,
    FilterState,
    FilterStatus,
    GlobalLocalizationCommand,
    ImageHeader,
    InitialPoseCommand,
    Odometry,
    ParticleCloud,
    PoseEstimate,
    UpdateRefusal,
    UpdateResult,
    WarpRequest,
)
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf_services.filter_loop.dispatcher import AddressedRequest, UnknownRequestError, UpdateDispatcher
from locnerf_services.filter_loop.frames import FilterFrames
from locnerf_services.filter_loop.image_hold import Frame, ImageHold
from locnerf_services.filter_loop.loop_state import LoopStateMachine
from locnerf_services.filter_loop.odometry_history import OdometryHistory
from locnerf_services.filter_loop.persistence import PosePersistence
from locnerf_services.rgbd import depth_request
from locnerf_services.runtime import BadMessages, RateMeter

logger = logging.getLogger(__name__)

Outgoing = list[tuple[str, bytes]]
"""Messages to publish: (key expression, payload bytes) pairs."""
GAP_PERIODS = 1.5
"""An odometry increment spanning more than this many nominal periods bridged a gap (counted as odometry_gaps)."""


class FilterLoopConfig(BaseModel):
    """Timing and fault handling of the filter loop."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    start: Literal["global", "wait"] = Field("global", description="Without a saved state: 'global' (localize over the map) or 'wait' (for a command).")
    update_timeout: float = Field(5.0, gt=0, description="An update not complete after this many seconds is abandoned.")
    max_in_flight: int = Field(2, ge=1, description="Updates in flight at once (2 keeps the workers busy while the filter merges).")
    max_shard_attempts: int = Field(
        3,
        ge=1,
        description="Sends of one update shard, to workers that vanished or refused it as failed, before the update is given up "
        "(updates_given_up): a shard that fails every worker is not passed on from worker to worker for ever.",
    )
    max_image_age: float = Field(1.0, gt=0, description="Images older than the newest odometry by more than this are dropped, seconds.")
    image_odometry_wait: float = Field(
        0.3,
        gt=0,
        description="Longest wait, seconds of the filter's clock, of an image stamped after the newest odometry for odometry at or after its "
        "stamp (so that the particles are carried to the image's stamp, not weighed at the older odometry's). VIO publishes after the "
        "camera; 0.3 s is between 4 and 5 periods of 15 Hz odometry. An image whose wait is over is dropped (images_odometry_wait_expired).",
    )
    updates_per_image: int = Field(
        1,
        ge=1,
        description="Updates on one image while no newer one has come: a repeat starts once the image's previous update has merged"
        " (cheap re-projection updates leave the workers idle between images otherwise).",
    )
    odometry_horizon: float = Field(5.0, gt=0, description="Seconds of odometry kept to carry particles to an image stamp.")
    odometry_rate: float = Field(
        15.0,
        gt=0,
        description="Nominal odometry rate, Hz: the prediction noise is per period of it. An increment across a gap of the odometry "
        "(a frame the odometry failed on) spans Δt > 1/rate and gets the noise of that time, σ·√(Δt·rate) (odometry_gaps counts them).",
    )
    odometry_resync: int = Field(
        3,
        ge=1,
        description="Consecutive odometry messages stamped before the newest accepted one (and increasing among themselves) "
        "after which the odometry clock is taken as stepped back: a new odometry session starts, as after a restart. "
        "A single stamp that jumped ahead thus blocks the pose stream for this many messages, not until the clock catches up.",
    )
    particles_rate: float = Field(2.0, gt=0, description="Particle clouds published per second.")
    status_rate: float = Field(1.0, gt=0, description="Status messages published per second.")
    state_file: str = Field("", description="File where the last pose is saved and resumed from on restart (empty: none).")
    max_image_pixels: int = Field(4096 * 4096, gt=0, description="Images whose header declares more pixels than this are dropped unread (bad_image_too_large).")
    state_save_rate: float = Field(1.0, gt=0, description="Saves of the state file per second at most (a writer thread does them, off the pose path).")
    T_body_cam: list[list[float]] = Field(
        default_factory=lambda: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        description="4×4 pose of the camera (locnerf's OpenGL axes: x right, y up, z back) in the odometry's body frame, metres. "
        "Odometry of the body is carried to the camera with it (the odometry history and the state file then hold the camera's "
        "odometry pose T_odom_body · T_body_cam); ROS 2 outputs give the body pose. Identity: the body is the camera. "
        "From an OpenCV/ROS optical-frame extrinsic T_body_optical (e.g. EuRoC's T_BS) it is opencv_to_opengl(T_body_optical).",
    )

    @field_validator("T_body_cam")
    @classmethod
    def _extrinsic(cls, value: list[list[float]]) -> list[list[float]]:
        return validate_pose_setting(value, "T_body_cam")


class FilterLoop:
    """Message-in, message-out wrapper of a :class:`Localizer`.

    Args:
        robot_id: key prefix.
        localizer: the particle filter (owned from now on; read it freely, its particles change
            only through :attr:`state_machine`).
        normalization: the map's frame and scale.
        region: plausible camera positions for global localization (map units).
        config: timing and fault handling.
        clock: monotonic seconds.
        map_checksum: identity of the map (:func:`locnerf.maps.source.map_identity`); only workers announcing it are sent updates.
    """

    def __init__(
        self,
        robot_id: str,
        localizer: Localizer,
        normalization: MapNormalization,
        region: SearchRegion,
        config: FilterLoopConfig,
        clock: Callable[[], float],
        map_checksum: str,
    ) -> None:
        self.robot_id = robot_id
        self.localizer = localizer
        self.state_machine = LoopStateMachine(localizer)
        self.frames = FilterFrames(normalization, torch.tensor(config.T_body_cam, dtype=torch.float64))
        self.persistence = PosePersistence(config.state_file, config.state_save_rate)
        self.region = region
        self.config = config
        self.clock = clock
        self.dispatcher = UpdateDispatcher(map_checksum, config.update_timeout, config.max_in_flight, config.max_shard_attempts)
        self.history = OdometryHistory(config.odometry_horizon)
        self.bad = BadMessages("filter_loop")
        self.rates = {name: RateMeter(clock=clock) for name in ("odometry", "pose", "image", "update")}
        self.latencies: collections.deque[float] = collections.deque(maxlen=20)
        self.images_replaced = 0
        self.images_replaced_upstream = 0
        self.images_received = 0
        self.images_without_depth = 0
        self.inbox_dropped = 0
        self.odometry_restarts = 0
        self.odometry_gaps = 0
        self.merge_failures = 0
        self._stepped_back: list[float] = []
        self._odometry_stamp_ns: int | None = None
        self._image: Frame | None = None
        self.held_images = ImageHold(config.image_odometry_wait)
        self._warned_no_depth = False
        self.depth_without_readings = 0
        self._image_uses = 0
        self._last_particles = self._last_status = -float("inf")
        self._start()

    # ------------------------------------------------------------------ initialisation
    def _start(self) -> None:
        saved = self.persistence.restore()
        if saved is not None:
            self._initialize_around(saved.T_world_cam, saved.covariance)
            self.history.append(saved.stamp, saved.T_odom_body)
        elif self.config.start == "global":
            self._initialize_over_map()

    def _initialize_over_map(self) -> None:
        self.state_machine.restart(lambda localizer: localizer.initialize_uniform(self.region))

    def _initialize_around(self, T_world_cam: torch.Tensor, covariance: torch.Tensor) -> None:
        mean, cov = self.frames.particle_distribution(T_world_cam, covariance)
        self.state_machine.restart(lambda localizer: localizer.initialize_gaussian(mean, cov))

    def refresh_estimate(self) -> bool:
        """Recompute the estimate if a merge has changed the particles since; whether it did.

        A merge only marks the estimate stale, so that the driver can publish a waiting pose
        between the merge and this pass over the particles; :meth:`handle_odometry` refreshes
        a stale estimate itself, so a pose always reflects every merged update."""
        return self.state_machine.refresh_estimate()

    def predict_pending(self) -> None:
        """Move the particles by the odometry already published as a pose (see :meth:`handle_odometry`).

        The driver calls this right after publishing the pose, off the pose's path; otherwise the
        state machine does it before the particles are next used."""
        self.state_machine.settled()

    @property
    def running(self) -> bool:
        """Whether the filter has particles."""
        return self.state_machine.running

    def _key(self, topic: keys.Topic, **fields: str) -> str:
        return keys.key(self.robot_id, topic, **fields)

    # ------------------------------------------------------------------ handlers
    def handle_odometry(self, payload: bytes) -> Outgoing:
        """Publish the pose at this odometry stamp; the particles' prediction follows.

        The pose is the last estimate computed from the particles, carried by every increment
        since as eq. 4 carries the particles (:func:`carry_estimate`: the mean moves with the
        odometry, the covariance grows by the prediction noise), so the pose costs no pass over
        the particles. The prediction itself (eq. 4 on every particle) is left pending until
        :meth:`predict_pending`, which the driver calls once the pose is out."""
        try:
            message = decode(payload, Odometry)
            pose = torch.tensor(message.T_odom_body, dtype=torch.float64)
            validate_poses(pose, name="T_odom_body")
            pose = self.frames.camera_odometry(pose)
            if self._odometry_clock_restarted(message.stamp):
                self.history.clear()
                self.odometry_restarts += 1
            previous = self.history.latest_stamp
            increment = self.history.append(message.stamp, pose)
            periods = 1.0 if previous is None else (message.stamp - previous) * self.config.odometry_rate
            if periods > GAP_PERIODS:
                self.odometry_gaps += 1
            self._odometry_stamp_ns = message.stamp_ns
            self._stepped_back.clear()
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
            return []
        except InvalidPoseError as error:
            self.bad.record("invalid_odometry", str(error))
            return []
        except ValueError as error:
            self._stepped_back.append(message.stamp)
            self.bad.record("stamp_backwards", str(error))
            return []
        self.rates["odometry"].tick()
        if not self.running:
            return []
        estimate = self.state_machine.carry(self.frames.map_increment(increment), periods)
        return [self._pose_message(message, estimate)]

    @property
    def latest_stamp_ns(self) -> int:
        """The newest odometry's stamp in whole nanoseconds, as it came (a resumed state's stamp is rounded;
        0 before any): the stamp of the particle cloud, the status and their ROS 2 counterparts."""
        if self._odometry_stamp_ns is not None:
            return self._odometry_stamp_ns
        return nanoseconds_from_seconds(self.history.latest_stamp or 0.0)

    def _odometry_clock_restarted(self, stamp: float) -> bool:
        """Whether ``stamp`` starts a new odometry session: it lies more than ``odometry_horizon``
        before the newest accepted stamp (a restarted source), or it ends a run of
        ``odometry_resync`` increasing stamps all before it (the clock stepped back, or the newest
        accepted stamp had jumped ahead)."""
        latest = self.history.latest_stamp
        if latest is None or stamp > latest:
            return False
        run = self._stepped_back
        if run and stamp <= run[-1]:
            run.clear()  # not increasing: a stray old message, not a clock that stepped back
        if stamp < latest - self.config.odometry_horizon:
            logger.warning("odometry stamps restarted (%.3f after %.3f): treating it as a new odometry session", stamp, latest)
            return True
        if len(run) + 1 >= self.config.odometry_resync:
            logger.warning(
                "odometry clock stepped back (%d stamps from %.3f before %.3f): new odometry session", len(run) + 1, run[0] if run else stamp, latest
            )
            return True
        return False

    def _pose_message(self, odometry: Odometry, estimate: ParticleEstimate) -> tuple[str, bytes]:
        """The pose at ``odometry``'s stamp (its exact nanoseconds too)."""
        metric = self.frames.metric_estimate(estimate)
        self.persistence.offer(odometry.stamp, metric.pose, metric.covariance, self.history.latest_pose)
        self.rates["pose"].tick()
        message = PoseEstimate(
            stamp=odometry.stamp,
            stamp_ns=odometry.stamp_ns,
            T_world_cam=metric.pose.tolist(),
            covariance=metric.covariance.tolist(),
            particle_count=estimate.particle_count,
            spread=metric.spread,
            effective_sample_size=estimate.effective_sample_size,
            mode=estimate.stage,
            epoch=self.localizer.epoch,
        )
        return self._key(keys.POSE), encode(message)

    def handle_image(self, payload: bytes) -> Outgoing:
        """Keep the newest valid image for the next update."""
        try:
            header, pixels, depth = decode_rgbd(payload, self.config.max_image_pixels)
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
            return []
        latest = self.history.latest_stamp
        if latest is not None and header.stamp < latest - self.config.max_image_age:
            self.bad.record("image_too_old", f"image stamp {header.stamp} is more than {self.config.max_image_age} s older than the odometry ({latest})")
            return []
        if latest is not None and header.stamp > latest + self.config.max_image_age:
            # No odometry places the particles at this stamp (odometry stopped, or the image's clock jumped ahead).
            self.bad.record("image_ahead", f"image stamp {header.stamp} is more than {self.config.max_image_age} s after the newest odometry ({latest})")
            return []
        self.rates["image"].tick()
        if latest is not None and header.stamp > latest:
            self.held_images.hold((header, pixels, depth), self.clock())  # until odometry reaches its stamp (image_hold.py)
        else:
            self._use_image((header, pixels, depth))
        return []

    def _use_image(self, frame: Frame) -> None:
        """Make ``frame`` the image of the next update (an unused older one is replaced, counted)."""
        if self._image is not None and self._image_uses == 0:
            self.images_replaced += 1
        self._image = frame
        self._image_uses = 0

    def handle_result(self, payload: bytes) -> Outgoing:
        """Store a shard's result; merge when the update is complete."""
        try:
            completed = self.dispatcher.receive(decode(payload, UpdateResult), self.clock())
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
            return []
        except UnknownRequestError as error:
            self.bad.record("unknown_request", str(error))
            return []
        except ValueError as error:
            self.bad.record("result_mismatch", str(error))
            return []
        if completed is None or not self.running:
            return []
        try:
            report = self.state_machine.merge(completed)
        except Exception:  # a fault of the filter must not end the filter thread: the update is dropped, counted
            self.merge_failures += 1
            if self.merge_failures == 1:
                logger.exception("merging an update failed: dropped (further failures are only counted, merge_failures)")
            return []
        if report.outcome is MergeOutcome.MERGED:
            self.rates["update"].tick()
            self.latencies.append(completed.latency)
        logger.debug(
            "update %s at odometry stamp %.2f s (%s): ESS %.1f, %d particles, stage %s",
            report.outcome,
            self.history.latest_stamp or 0.0,
            "re-projected" if completed.warped else "rendered",
            report.effective_sample_size,
            report.particle_count,
            report.stage,
        )
        if report.injected:
            logger.info("odometry stamp %.2f s: %d recovery particles injected", self.history.latest_stamp or 0.0, report.injected)
        return []

    def handle_refusal(self, payload: bytes) -> Outgoing:
        """A worker refused a shard: re-send it to another worker or give the update up, at once."""
        try:
            return self._requests(self.dispatcher.refused(decode(payload, UpdateRefusal)))
        except DecodeError as error:
            self.bad.record(error.kind, error.reason)
        except UnknownRequestError as error:
            self.bad.record("unknown_request", str(error))
        except ValueError as error:
            self.bad.record("result_mismatch", str(error))
        return []

    def handle_initial_pose(self, payload: bytes) -> Outgoing:
        """Re-initialise around the commanded metric pose, carried from its stamp to the newest odometry (:meth:`_carried_to_odometry`)."""
        try:
            command = decode(payload, InitialPoseCommand)
            pose = torch.tensor(command.T_world_cam, dtype=torch.float64)
            validate_poses(pose, name="initial pose")
        except DecodeError as error:
            self.bad.record(f"command_{error.kind}", error.reason)
            return []
        except InvalidPoseError as error:
            self.bad.record("command_invalid", str(error))
            return []
        logger.info("initial pose command: re-initialising")
        self._initialize_around(*self._carried_to_odometry(command.stamp, pose, torch.tensor(command.covariance, dtype=torch.float64)))
        return []

    def _carried_to_odometry(self, stamp: float, T_world_cam: torch.Tensor, covariance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A metric pose (4, 4) with its (6, 6) covariance at ``stamp``, carried to the newest odometry stamp, as
        amcl carries an initial pose from its stamp to now: ``T(now) = T(stamp) · O`` with the odometry
        increment ``O = T_odom_cam(stamp)⁻¹ · T_odom_cam(now)``, and ``Σ(now) = Ad(O⁻¹) Σ Ad(O⁻¹)ᵀ`` (the
        uncertainty moves with the pose; no prediction noise is added). A stamp outside the odometry
        history (older than kept, or newer than the newest odometry) is used as is, logged; so is any
        stamp before odometry has come."""
        latest = self.history.latest_stamp
        if latest is None:
            return T_world_cam, covariance
        if stamp > latest:
            logger.info("initial pose stamped %.9f s, after the newest odometry (%.9f s): used as the pose at the newest odometry", stamp, latest)
            return T_world_cam, covariance
        try:
            back = self.history.carry_to(stamp)  # T_now_stamp; None when stamp is the newest odometry's
        except ValueError as error:
            logger.warning("initial pose used as the pose at the newest odometry (%.9f s), not carried: %s", latest, error)
            return T_world_cam, covariance
        if back is None:
            return T_world_cam, covariance
        to_now = adjoint(back)  # Ad(O⁻¹), O = back⁻¹
        return T_world_cam @ pose_inverse(back), to_now @ covariance @ to_now.T

    def handle_global_localization(self, payload: bytes) -> Outgoing:
        """Re-initialise over the whole map."""
        try:
            decode(payload, GlobalLocalizationCommand)
        except DecodeError as error:
            self.bad.record(f"command_{error.kind}", error.reason)
            return []
        logger.info("global localization command: re-initialising over the map")
        self._initialize_over_map()
        return []

    def worker_changed(self, token_key: str, alive: bool) -> Outgoing:
        """A worker's liveliness token appeared or vanished (one announcing another map: counted, left out)."""
        try:
            token = keys.parse_worker_token(token_key)
        except ValueError as error:
            self.bad.record("bad_token", str(error))
            return []
        logger.info("worker %s (%s, map %s) %s", token.worker_id, token.device, token.map_checksum, "joined" if alive else "left")
        return self._requests(self.dispatcher.worker_changed(token, alive))

    def _requests(self, addressed: list[AddressedRequest]) -> Outgoing:
        return [(self._key(keys.UPDATE_REQUEST, worker_id=worker), encode(request)) for worker, request in addressed]

    def close(self) -> None:
        """Stop the state writer after writing the last pose (if a state file is configured)."""
        self.persistence.close()

    # ------------------------------------------------------------------ periodic work
    def tick(self) -> Outgoing:
        """Expire or start an update; publish particles and status when due."""
        now = self.clock()
        self.dispatcher.expire(now)
        released = self.held_images.release(self.history.latest_stamp, now)
        if released is not None:
            self._use_image(released)
        out: Outgoing = []
        repeat = self._image_uses > 0
        if self.running and self._image is not None and self.dispatcher.can_start and not (repeat and self.dispatcher.pending):
            out += self._start_update(now)
        if self.running and now - self._last_particles >= 1.0 / self.config.particles_rate:
            self._last_particles = now
            out.append(self._particles_message())
        return out + self.status_if_due()

    def status_if_due(self) -> Outgoing:
        """The status message when its period has passed (``status_rate``), else nothing."""
        now = self.clock()
        if now - self._last_status < 1.0 / self.config.status_rate:
            return []
        self._last_status = now
        return [(self._key(keys.STATUS), encode(self.status()))]

    def _start_update(self, now: float) -> Outgoing:
        header, pixels, depth = self._image
        self._image_uses += 1
        if self._image_uses >= self.config.updates_per_image:
            self._image = None
        try:
            carry = self.history.carry_to(header.stamp)
        except ValueError as error:
            self.bad.record("image_too_old", str(error))
            return []
        localizer = self.state_machine.settled()
        intrinsics = header.intrinsics
        image = torch.from_numpy(pixels).float() / 255.0
        localizer.seed_from_image(image, intrinsics)
        snapshot = localizer.snapshot(self.frames.map_increment(carry))
        measurement = localizer.config.measurement
        chosen = sample_pixels_of_image(image, measurement, localizer.generator, measurement.pixels_for(len(snapshot.ids)))
        colours = observed_colours(image, chosen)
        kept = image if localizer.keyframes is not None else None
        reference = localizer.warp_reference(snapshot)
        warp = None
        if reference is not None:
            seed = int(torch.randint(2**62, (1,), generator=localizer.generator))
            warp = WarpRequest(reference_pose=reference.tolist(), seed=seed, measurement=measurement, image=np.ascontiguousarray(pixels).tobytes())
        depth_part = self._depth_part(header, depth, measurement, localizer.generator)
        addressed = self.dispatcher.start(
            snapshot,
            chosen,
            colours,
            intrinsics,
            measurement.exponent,
            now,
            kept,
            measurement.exposure_gain_range,
            warp,
            depth_part,
            localizer.search_for(snapshot, image),
        )
        return self._requests(addressed)

    def _depth_part(self, header: ImageHeader, depth: np.ndarray | None, measurement: MeasurementConfig, generator: torch.Generator) -> DepthRequest | None:
        """The depth term of an update when the localizer weighs depth and the frame has it (warned once when it has not)."""
        if measurement.depth is None:
            return None
        if depth is None or header.depth is None:
            if not self._warned_no_depth:
                logger.warning("measurement.depth is set but the images carry no depth: weighing colour only")
                self._warned_no_depth = True
            return None
        try:
            return depth_request(depth, header.depth, measurement, self.frames.normalization.scale, generator)
        except ValueError as error:
            if self.depth_without_readings == 0:
                logger.warning("an RGB-D frame's depth is left out (further ones are only counted): %s", error)
            self.depth_without_readings += 1
            return None

    def metric_particle_poses(self) -> torch.Tensor:
        """(N, 4, 4) float64 camera poses of the particles, metric, in the map's world frame (needs particles)."""
        return self.frames.metric_poses(self.state_machine.settled().particles.poses)

    def _particles_message(self) -> tuple[str, bytes]:
        poses = self.metric_particle_poses()
        message = ParticleCloud(
            stamp_ns=self.latest_stamp_ns, positions=poses[:, :3, 3].tolist(), weights=self.localizer.particles.weights.double().cpu().tolist()
        )
        return self._key(keys.PARTICLES), encode(message)

    def counters(self) -> dict[str, int]:
        """Every count the status reports."""
        merged = self.localizer.counters
        counts = {
            "updates_merged": merged["merged"],
            "stale_results": merged["stale"],
            "degenerate_updates": merged["degenerate"],
            "updates_tempered": merged["tempered"],
            "recoveries": merged["recoveries"],
            "particles_injected": merged["injected"],
            "searches": merged["searches"],
            "searches_moved": merged["searches_moved"],
            "drops_in_place": merged["drops_in_place"],
            "merge_failures": self.merge_failures,
            "images_replaced": self.images_replaced + self.images_replaced_upstream + self.held_images.replaced,
            "images_waited_for_odometry": self.held_images.released,
            "images_odometry_wait_expired": self.held_images.expired,
            "bad_messages": self.bad.total,
            "odometry_restarts": self.odometry_restarts,
            "odometry_gaps": self.odometry_gaps,
            "inbox_dropped": self.inbox_dropped,
            "images_received": self.images_received,
            "images_without_depth": self.images_without_depth,
            "state_save_failures": self.persistence.failures,
            "depth_without_readings": self.depth_without_readings,
        }
        counts |= dict(self.dispatcher.counters)
        counts |= {f"bad_{kind}": count for kind, count in self.bad.counts.items()}
        return counts

    def status(self) -> FilterStatus:
        """The current health summary."""
        return FilterStatus(
            stamp_ns=self.latest_stamp_ns,
            state=FilterState.RUNNING if self.running else FilterState.WAITING_FOR_INITIALISATION,
            rates_hz={name: meter.rate() for name, meter in self.rates.items()},
            update_latency_s=sum(self.latencies) / len(self.latencies) if self.latencies else None,
            in_flight=self.dispatcher.in_flight,
            workers=sorted(self.dispatcher.workers),
            workers_on_another_map=sorted(self.dispatcher.other_map),
            map_checksum=self.dispatcher.map_checksum,
            counters=self.counters(),
        )
