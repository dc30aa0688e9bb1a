"""Wire schemas: one pydantic model per message type, all frozen, all fields documented.

Poses on the wire are metric 4×4 matrices (row-major nested lists) in the map's world frame
(OpenGL camera axes, as everywhere in locnerf). Update requests and results are the exception:
they carry the filter's particles in map units, since worker and filter share one map.
"""

from __future__ import annotations

import enum
import math
from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from locnerf.filter.annealing import AnnealingStage
from locnerf.filter.measurement_config import ExposureGainRange, MeasurementConfig
from locnerf.filter.search_config import MAX_PIXELS, CrossEntropyConfig
from locnerf.messages.stamps import NANOSECONDS_PER_SECOND, nanoseconds_from_seconds, seconds_from_nanoseconds
from locnerf.render.camera import PinholeIntrinsics

Matrix = list[list[float]]


def _check_matrix(value: Matrix, rows: int, cols: int, name: str) -> Matrix:
    if len(value) != rows or any(len(row) != cols for row in value):
        shape = (len(value), len(value[0]) if value else 0)
        raise ValueError(f"{name}: expected a {rows}×{cols} matrix, got shape {shape}")
    if not all(math.isfinite(x) for row in value for x in row):
        raise ValueError(f"{name}: expected finite entries, got {value}")
    return value


def _check_pose(value: Matrix, name: str) -> Matrix:
    _check_matrix(value, 4, 4, name)
    if any(abs(a - b) > 1e-9 for a, b in zip(value[3], (0.0, 0.0, 0.0, 1.0))):
        raise ValueError(f"{name}: expected last row [0, 0, 0, 1], got {value[3]}")
    return value


def _check_depth_offset(value: Matrix) -> Matrix:
    """``T_cam_depth``: a finite 4×4 rigid transform (:func:`locnerf.geometry.validation.validate_pose_setting`).

    Its torch is imported here, not with the module: the command-line clients and the router read these schemas and
    never meet a depth image."""
    from locnerf.geometry.validation import validate_pose_setting

    return validate_pose_setting(_check_pose(value, "T_cam_depth"), "T_cam_depth")


DepthOffset = Annotated[Matrix, AfterValidator(_check_depth_offset)]
"""The depth camera's pose in the colour camera's frame: 4×4, metres, OpenGL axes."""

PoseMatrix = Annotated[Matrix, AfterValidator(lambda value: _check_pose(value, "pose"))]
"""A 4×4 pose: finite, last row [0, 0, 0, 1]."""

Covariance6 = Annotated[Matrix, AfterValidator(lambda value: _check_matrix(value, 6, 6, "covariance"))]
"""A finite 6×6 covariance in a pose's tangent space (rotation first)."""


def _check_covariance(value: Matrix, name: str) -> Matrix:
    """6×6, finite, symmetric, positive semi-definite (checked with a Cholesky of cov + εI)."""
    _check_matrix(value, 6, 6, name)
    matrix = np.array(value, dtype=np.float64)
    if not np.allclose(matrix, matrix.T, atol=1e-9 * (1 + float(np.abs(matrix).max()))):
        raise ValueError(f"{name}: expected a symmetric matrix")
    jitter = 1e-12 * (1 + float(np.abs(matrix.diagonal()).max()))
    try:
        np.linalg.cholesky(matrix + jitter * np.eye(6))
    except np.linalg.LinAlgError:
        raise ValueError(f"{name}: expected a positive semi-definite matrix, eigenvalues {np.linalg.eigvalsh(matrix).tolist()}") from None
    return value


class _Wire(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


MAX_ABS_STAMP = 1e10
"""Largest accepted |stamp|, seconds (Unix time of the year 2286): beyond it a stamp is garbage."""

STAMP_AGREEMENT = 1e-6
"""Largest accepted |stamp − stamp_ns·1e-9|, seconds: float seconds below MAX_ABS_STAMP round whole nanoseconds by at most 0.95 µs."""


class Stamped(_Wire):
    """Base of time-stamped messages. A sender gives ``stamp``, ``stamp_ns`` or both (they must agree
    to within STAMP_AGREEMENT); the missing one is derived (:mod:`locnerf.messages.stamps`)."""

    stamp: float = Field(description="Time of the measurement or state, seconds (sensor clock): stamp_ns / 1e9, rounded to a double.")
    stamp_ns: int = Field(
        description="The same time in whole nanoseconds, exact: a ROS 2 stamp (sec, nanosec) passes through unchanged, where float "
        "seconds near 1.7e9 s are 238 ns apart. Outputs take their input's stamp_ns."
    )
    frame_id: str = Field("map", description="Frame the pose or data refer to.")

    @model_validator(mode="before")
    @classmethod
    def _derive_missing_stamp(cls, data: Any) -> Any:
        """Fill the missing one of ``stamp`` and ``stamp_ns`` from the other (when that one is a finite number; the fields' own checks report the rest)."""
        if not isinstance(data, dict) or ("stamp" in data) == ("stamp_ns" in data):
            return data
        if "stamp" in data:
            seconds = data["stamp"]
            if isinstance(seconds, int | float) and not isinstance(seconds, bool) and math.isfinite(seconds):
                return {**data, "stamp_ns": nanoseconds_from_seconds(seconds)}
        elif type(data["stamp_ns"]) is int:
            return {**data, "stamp": seconds_from_nanoseconds(data["stamp_ns"])}
        return data

    @field_validator("stamp")
    @classmethod
    def _finite_stamp(cls, value: float) -> float:
        if not math.isfinite(value) or abs(value) >= MAX_ABS_STAMP:
            raise ValueError(f"stamp={value}: expected a finite number of seconds below {MAX_ABS_STAMP:g} in magnitude")
        return value

    @field_validator("stamp_ns")
    @classmethod
    def _bounded_stamp_ns(cls, value: int) -> int:
        if abs(value) >= int(MAX_ABS_STAMP) * NANOSECONDS_PER_SECOND:
            raise ValueError(f"stamp_ns={value}: expected whole nanoseconds below {MAX_ABS_STAMP:g} s in magnitude")
        return value

    @model_validator(mode="after")
    def _stamps_agree(self) -> Stamped:
        if abs(self.stamp - seconds_from_nanoseconds(self.stamp_ns)) > STAMP_AGREEMENT:
            raise ValueError(f"stamp={self.stamp} s and stamp_ns={self.stamp_ns}: expected the same time (to {STAMP_AGREEMENT:g} s)")
        return self


def _check_size(width: int, height: int, intrinsics: PinholeIntrinsics, name: str) -> None:
    if (width, height) != (intrinsics.width, intrinsics.height):
        raise ValueError(f"{name} size {width}×{height} does not match the intrinsics {intrinsics.width}×{intrinsics.height}")


DEPTH_ENCODING = "16UC1"
"""Depth pixels on the wire: uint16 millimetres along the depth camera's optical axis, 0 = no reading, little-endian."""


class DepthHeader(_Wire):
    """The depth image of an RGB-D frame, whose pixels follow the colour pixels (see :mod:`.codec`).

    The depth camera sits at the colour camera's pose times ``T_cam_depth`` (at the same pose when
    unset, as registered RGB-D cameras and most data sets have it) with its own intrinsics; its pixels
    are never resampled onto the colour grid."""

    encoding: str = Field(DEPTH_ENCODING, description="Pixel layout: 16UC1 (row-major, H×W uint16 millimetres, little-endian, 0 = no reading).")
    width: int = Field(gt=0, description="Depth image width, pixels.")
    height: int = Field(gt=0, description="Depth image height, pixels.")
    intrinsics: PinholeIntrinsics = Field(description="Depth camera intrinsics (OpenCV pixel-centre convention).")
    T_cam_depth: DepthOffset | None = Field(
        None, description="4×4 pose of the depth camera in the colour camera's frame, metres, OpenGL axes; None: the same pose."
    )

    @model_validator(mode="after")
    def _valid(self) -> DepthHeader:
        if self.encoding != DEPTH_ENCODING:
            raise ValueError(f"depth encoding {self.encoding!r}: expected {DEPTH_ENCODING!r}")
        _check_size(self.width, self.height, self.intrinsics, "depth image")
        return self


class ImageHeader(Stamped):
    """Header of an image frame; the pixels follow as raw bytes (see :mod:`.codec`), then the depth pixels of an RGB-D frame."""

    encoding: str = Field(description="Pixel layout of the payload: rgb8 or bgr8 (row-major, H×W×3 uint8).")
    width: int = Field(gt=0, description="Image width, pixels.")
    height: int = Field(gt=0, description="Image height, pixels.")
    intrinsics: PinholeIntrinsics = Field(description="Camera intrinsics of this frame (OpenCV pixel-centre convention).")
    depth: DepthHeader | None = Field(None, description="The depth image taken with this frame (RGB-D cameras); None: colour only.")

    @model_validator(mode="after")
    def _size_matches_intrinsics(self) -> ImageHeader:
        _check_size(self.width, self.height, self.intrinsics, "image")
        return self


class Odometry(Stamped):
    """Stamped VIO output: the body pose in the odometry frame (metres)."""

    T_odom_body: Matrix = Field(description="4×4 body-to-odometry-frame pose, metres.")
    covariance: Matrix | None = Field(None, description="Optional 6×6 covariance of the pose, tangent (rotation, translation).")

    @field_validator("T_odom_body")
    @classmethod
    def _pose(cls, value: Matrix) -> Matrix:
        return _check_pose(value, "T_odom_body")

    @field_validator("covariance")
    @classmethod
    def _covariance(cls, value: Matrix | None) -> Matrix | None:
        return None if value is None else _check_covariance(value, "covariance")


class PoseStamped(Stamped):
    """A metric camera pose in the map's world frame (used for ground truth)."""

    T_world_cam: Matrix = Field(description="4×4 camera-to-world pose, metres, OpenGL camera axes.")

    @field_validator("T_world_cam")
    @classmethod
    def _pose(cls, value: Matrix) -> Matrix:
        return _check_pose(value, "T_world_cam")


class PoseEstimate(PoseStamped):
    """The filter's estimate, published at the odometry rate."""

    covariance: Matrix = Field(description="6×6 covariance in the tangent space of the mean, (rotation, translation), metric.")
    particle_count: int = Field(ge=0, description="Particles in the filter.")
    spread: float = Field(ge=0, description="Weighted spread of particle positions, metres.")
    effective_sample_size: float = Field(
        ge=0,
        description="Effective sample size 1 / Σ w² of the weights the last merged update gave, before resampling (the particle count after an initialisation).",
    )
    mode: AnnealingStage = Field(description="Annealing stage of the filter (coarse, refine, super_refine).")
    epoch: int = Field(ge=0, description="Initialisation epoch of the filter.")

    @field_validator("covariance")
    @classmethod
    def _covariance(cls, value: Matrix) -> Matrix:
        return _check_covariance(value, "covariance")


class ParticleCloud(Stamped):
    """Particle positions and weights (metres, map's world frame), at a lower rate than the pose."""

    positions: list[list[float]] = Field(description="(N, 3) particle positions, metres.")
    weights: list[float] = Field(description="(N,) normalised particle weights.")

    @model_validator(mode="after")
    def _lengths(self) -> ParticleCloud:
        if len(self.positions) != len(self.weights) or any(len(p) != 3 for p in self.positions):
            raise ValueError(f"particle cloud: expected positions (N, 3) and weights (N,), got {len(self.positions)} and {len(self.weights)}")
        return self


class FilterState(enum.StrEnum):
    """Whether the filter is localizing (the ``state`` of a FilterStatus)."""

    WAITING_FOR_INITIALISATION = "waiting_for_initialisation"
    """No particles yet: waiting for an initial pose or a global-localization command."""
    RUNNING = "running"
    """Particles exist: every odometry message gets a pose."""


class FilterStatus(Stamped):
    """Health of the filter loop."""

    state: FilterState = Field(description="waiting_for_initialisation or running.")
    rates_hz: dict[str, float] = Field(description="Measured rates: odometry, pose, image, update.")
    update_latency_s: float | None = Field(description="Mean time from update request to merge over the last updates, seconds.")
    in_flight: int = Field(ge=0, description="Update shards sent and not yet answered.")
    workers: list[str] = Field(description="Ids of the live NeRF workers.")
    workers_on_another_map: list[str] = Field(
        default_factory=list, description="Ids of the live NeRF workers left out because they hold another map than the filter's (see map_checksum)."
    )
    map_checksum: str = Field(description="Identity of the filter's map (SHA-256 hex); only workers announcing the same are sent updates.")
    counters: dict[str, int] = Field(description="Counts: updates merged, stale, timed out, retried, dropped images, bad messages by kind.")


class ServiceStatus(Stamped):
    """Health of a worker or ingest process: its counters, like FilterStatus's, 1 Hz."""

    service: str = Field(description="nerf_worker or sensor_ingest.")
    instance: str = Field(description="Worker id or ingest id.")
    counters: dict[str, int] = Field(description="Counts: messages handled, bad messages by kind (bad_<kind>, bad_messages), inbox drops.")


class WarpRequest(_Wire):
    """Weigh the shard by re-projection (:mod:`locnerf.filter.warp`) instead of rendering from every pose.

    Every shard of an update carries the same reference pose, seed and image, so every worker draws
    the same reference pixels and the shards' likelihoods compare."""

    reference_pose: Matrix = Field(description="4×4 reference camera pose (the cloud's weighted mean), map units.")
    seed: int = Field(ge=0, lt=2**63, description="Seed of the draw of the reference pixels.")
    measurement: MeasurementConfig = Field(description="Pixel sampling and the warp settings (its `warp` must be set).")
    image: bytes = Field(description="The observed image, H×W×3 uint8 RGB row-major (H, W of the request's intrinsics).")

    @field_validator("reference_pose")
    @classmethod
    def _pose(cls, value: Matrix) -> Matrix:
        return _check_pose(value, "reference_pose")

    @field_validator("measurement")
    @classmethod
    def _has_warp(cls, value: MeasurementConfig) -> MeasurementConfig:
        if value.warp is None:
            raise ValueError("measurement.warp is None: expected the warp settings of a re-projection update")
        return value


class DepthRequest(_Wire):
    """The depth term of an update on an RGB-D frame (:mod:`locnerf.filter.depth_measurement`); every shard carries the same."""

    image: bytes = Field(description="The observed depth image: H×W uint16 millimetres, little-endian, 0 = no reading (H, W of `intrinsics`).")
    intrinsics: PinholeIntrinsics = Field(description="The depth camera.")
    T_cam_depth: DepthOffset | None = Field(
        None, description="4×4 pose of the depth camera in the particle (colour) camera's frame, metres, OpenGL axes; None: at the particle pose."
    )
    measurement: MeasurementConfig = Field(description="The measurement settings (its `depth` must be set).")
    pixels: list[list[float]] = Field(
        description="(M, 2) depth pixels (u, v) rendered from every pose, or looked up in the surface-distance layer (likelihood surface_distance);"
        " rendered-depth re-projection instead draws its points from the reference render."
    )

    @model_validator(mode="after")
    def _valid(self) -> DepthRequest:
        if self.measurement.depth is None:
            raise ValueError("measurement.depth is None: expected the depth settings of an RGB-D update")
        expected = self.intrinsics.width * self.intrinsics.height * 2
        if len(self.image) != expected:
            raise ValueError(
                f"depth request: image of {len(self.image)} bytes, expected {expected} for {self.intrinsics.width}×{self.intrinsics.height} uint16"
            )
        size = (self.intrinsics.width, self.intrinsics.height)
        if not self.pixels or any(len(p) != 2 or not (0 <= p[0] < size[0] and 0 <= p[1] < size[1]) for p in self.pixels):
            raise ValueError(f"depth request: expected 1 or more pixels (u, v) inside the {size[0]}×{size[1]} depth image")
        return self


def _pixels_match_colours(pixels: list[list[float]], colours: list[list[float]]) -> bool:
    """Whether ``pixels`` is (M, 2) and ``colours`` (M, 3), the same M."""
    return len(pixels) == len(colours) and all(len(p) == 2 for p in pixels) and all(len(c) == 3 for c in colours)


class SearchRequest(_Wire):
    """Search the cloud's estimate on the shard's own likelihood (its pixels, reference and depth points) by the
    cross-entropy method (:func:`locnerf.filter.final_search.cross_entropy_search`); only shard 0 carries it."""

    mean: PoseMatrix = Field(description="4×4 start of the search (the snapshot's weighted mean), map units.")
    covariance: Covariance6 = Field(description="6×6 covariance of the cloud in the tangent space of `mean` (rotation first), map units and radians.")
    config: CrossEntropyConfig = Field(description="The search's budget and spreads.")
    seed: int = Field(ge=0, lt=2**63, description="Seed of the search's draws.")
    pixels: list[list[float]] | None = Field(
        None, max_length=MAX_PIXELS, description="(M, 2) the search's own colour pixels (u, v), rendered in place of the shard's; None: the shard's."
    )
    observed_rgb: list[list[float]] | None = Field(None, max_length=MAX_PIXELS, description="(M, 3) observed colours in [0, 1] of `pixels`.")

    @model_validator(mode="after")
    def _own_pixels(self) -> SearchRequest:
        if (self.pixels is None) != (self.observed_rgb is None):
            raise ValueError("search request: expected both pixels and observed_rgb, or neither")
        if self.pixels is not None and (not self.pixels or not _pixels_match_colours(self.pixels, self.observed_rgb)):
            raise ValueError("search request: expected pixels (M, 2) and observed_rgb (M, 3) of equal length M >= 1")
        return self


class SearchFound(_Wire):
    """What a :class:`SearchRequest` found."""

    pose: PoseMatrix = Field(description="4×4 best pose found, map units.")
    log_likelihood: float = Field(description="Its log-likelihood on the shard's pixels.")
    start_log_likelihood: float = Field(description="The start's, on the same pixels.")


class UpdateRequest(_Wire):
    """One shard of an update: render ``pixels`` from every pose and compare with ``observed_rgb``."""

    request_id: str = Field(description="Id shared by all shards of one update.")
    shard: int = Field(ge=0, description="Index of this shard within the update.")
    map_checksum: str = Field(
        description="Identity of the filter's map (SHA-256 hex, locnerf.maps.source.map_identity), which the poses, pixels, warp and depth "
        "parts refer to; a worker holding another map refuses the request (UpdateRefusal, wrong_map)."
    )
    epoch: int = Field(ge=0, description="Filter epoch of the snapshot.")
    generation: int = Field(ge=0, description="Particle generation of the snapshot.")
    ids: list[int] = Field(description="(K,) particle ids.")
    poses: list[list[float]] = Field(description="(K, 16) row-major particle poses, map units.")
    pixels: list[list[float]] = Field(description="(M, 2) pixel coordinates (u, v).")
    observed_rgb: list[list[float]] = Field(description="(M, 3) observed colours in [0, 1].")
    intrinsics: PinholeIntrinsics = Field(description="The observing camera.")
    exponent: float = Field(4.0, gt=0, description="γ of the likelihood (M / SSE)^γ.")
    exposure_gain_range: ExposureGainRange = Field(
        None,
        description="Exposure-invariant likelihood: bounds of the per-particle gain fitted to the observed pixels (measurement.exposure_gain_range); None: off.",
    )
    warp: WarpRequest | None = Field(None, description="Re-projection instead of rendering; a worker whose map cannot place surfaces renders `pixels` instead.")
    depth: DepthRequest | None = Field(None, description="The depth term of an RGB-D frame, added to the colour term; None: colour only.")
    search: SearchRequest | None = Field(None, description="A search of the estimate on this shard's likelihood (after a relocalization); None: none.")

    @model_validator(mode="after")
    def _shapes(self) -> UpdateRequest:
        if len(self.poses) != len(self.ids) or any(len(p) != 16 for p in self.poses):
            raise ValueError(f"update request: expected poses (K, 16) for K={len(self.ids)} ids")
        if not _pixels_match_colours(self.pixels, self.observed_rgb):
            raise ValueError("update request: expected pixels (M, 2) and observed_rgb (M, 3) of equal length")
        expected = self.intrinsics.width * self.intrinsics.height * 3
        if self.warp is not None and len(self.warp.image) != expected:
            raise ValueError(
                f"update request: warp image of {len(self.warp.image)} bytes, expected {expected} for {self.intrinsics.width}×{self.intrinsics.height}×3"
            )
        return self


class UpdateResult(_Wire):
    """Per-particle log-likelihoods of one shard."""

    request_id: str = Field(description="Id of the update this shard belongs to.")
    shard: int = Field(ge=0, description="Index of the shard.")
    worker_id: str = Field(description="Worker that computed it.")
    epoch: int = Field(ge=0, description="Filter epoch of the snapshot (copied from the request).")
    generation: int = Field(ge=0, description="Particle generation of the snapshot (copied from the request).")
    ids: list[int] = Field(description="(K,) particle ids.")
    log_likelihoods: list[float] = Field(description="(K,) log-likelihoods (−inf allowed).")
    compute_seconds: float = Field(ge=0, description="Worker time spent on the shard.")
    search: SearchFound | None = Field(None, description="The result of the request's search; None when it carried none.")

    @model_validator(mode="after")
    def _lengths(self) -> UpdateResult:
        if len(self.ids) != len(self.log_likelihoods):
            raise ValueError(f"update result: {len(self.ids)} ids but {len(self.log_likelihoods)} log-likelihoods")
        return self


class RefusalReason(enum.StrEnum):
    """Why a worker answers a request with an :class:`UpdateRefusal` instead of a result."""

    WRONG_MAP = "wrong_map"
    """The request's map_checksum is not the worker's map."""
    BAD_REQUEST = "bad_request"
    """The request's content cannot be evaluated (non-rigid poses, pixels outside the image, a depth part the term refuses)."""
    FAILED = "failed"
    """The computation failed on this worker (e.g. out of GPU memory); another worker may succeed."""


class UpdateRefusal(_Wire):
    """A worker's answer to a request it did not compute, so that the filter re-sends the shard or gives the update up at once."""

    request_id: str = Field(description="Id of the update the refused shard belongs to.")
    shard: int = Field(ge=0, description="Index of the shard.")
    worker_id: str = Field(description="Worker that refused it.")
    reason: RefusalReason = Field(description="wrong_map, bad_request or failed.")
    detail: str = Field(max_length=1000, description="What went wrong, for the logs (the exception's message, shortened).")
    map_checksum: str = Field(description="Identity of the worker's map (SHA-256 hex).")


class InitialPoseCommand(PoseStamped):
    """Re-initialise the filter around a metric pose with a 6×6 covariance (rotation, translation)."""

    covariance: Matrix = Field(description="6×6 covariance of the initial pose, tangent (rotation rad², translation m²).")

    @field_validator("covariance")
    @classmethod
    def _covariance(cls, value: Matrix) -> Matrix:
        return _check_covariance(value, "covariance")


class GlobalLocalizationCommand(Stamped):
    """Re-initialise the filter over the whole map (positions uniform, yaw uniform)."""


WIRE_TYPES: dict[str, type[_Wire]] = {
    model.__name__: model
    for model in (
        ImageHeader,
        Odometry,
        PoseStamped,
        PoseEstimate,
        ParticleCloud,
        FilterStatus,
        ServiceStatus,
        UpdateRequest,
        UpdateResult,
        UpdateRefusal,
        InitialPoseCommand,
        GlobalLocalizationCommand,
    )
}
