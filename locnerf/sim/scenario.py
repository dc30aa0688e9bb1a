"""A simulated run: true camera path, drifting odometry, images, an optional kidnapping.

Everything lives on the odometry grid ``t_k = k / odom_rate`` (both ends of the run included);
images are taken at a subset of those stamps, so an image and the odometry message of its stamp
describe the same instant. The path (:mod:`locnerf.sim.paths`) gives the true camera poses and
the images; the odometry of the body is simulated by :func:`locnerf.sim.sensors.simulate_odometry`.

A kidnapping at ``t*`` makes the true path jump ahead (``τ(t) = t + shift`` from then on,
``shift`` = the configured ``kidnap_shift``, by default the path's: about half a loop). The odometry does not see the jump: its
increment across ``t*`` is the motion the camera would have made without it, every other
increment is the true one (then drift and noise are applied).

A run is simulated in segments of at most :data:`SEGMENT_TICKS` stamps, each continuing the
odometry and the noise draws of the one before, so a day-long stream of the services costs the
memory of one segment; :func:`build_scenario` joins them for the offline evaluation, and the
ingest streams them (:mod:`locnerf.sim.stream`): both see the same data for the same seed.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization
from locnerf.filter.depth_measurement import DepthObservation
from locnerf.geometry import pose_inverse, relative_pose
from locnerf.odometry.tracks import OdometryTrack
from locnerf.sim.paths import CameraPath
from locnerf.sim.sensors import VioConfig, simulate_odometry

SEGMENT_TICKS = 1 << 15
"""Odometry stamps simulated at once: about 36 minutes at 15 Hz."""


class ScenarioConfig(BaseModel):
    """Rates, odometry errors and the kidnapping of a simulated run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    duration: float | None = Field(None, gt=0, description="Length of the run, seconds; None: one loop of the path.")
    image_rate: float = Field(3.0, ge=0, description="Images per second (rounded onto the odometry grid or the frames); 0: odometry only.")
    vio: VioConfig = Field(default_factory=VioConfig, description="Odometry rate, drift and noise (metres, radians).")
    kidnap_at: float | None = Field(None, gt=0, description="Time of the kidnapping, seconds; None: no kidnapping.")
    kidnap_shift: float | None = Field(
        None,
        gt=0,
        description="Seconds along the path the kidnapping moves the camera ahead (locnerf.sim.kidnap picks one by distance); None: about half a loop.",
    )
    seed: int = Field(0, description="Seed of the odometry noise (the images draw from seed + 1).")


@dataclass(frozen=True)
class TrackingScenario:
    """A simulated run's data on the odometry grid (a whole run, or one segment of it).

    Attributes:
        stamps: (K,) float64 odometry stamps, seconds.
        truth: (K, 4, 4) float64 true ``T_world_cam`` in the map frame.
        odometry: (K, 4, 4) float64 ``T_odom_body``, metric (the body carries the camera at ``path.T_body_cam``).
        image_ticks: indices into ``stamps`` at which an image is taken, increasing.
        kidnap_tick: index of the first pose after the jump, or None.
        path_times: (K,) float64 time along the path at each stamp (jumps at the kidnapping).
        path: where the poses and images come from.
        odometry_valid: (K,) bool: stamps with odometry (real odometry has gaps); None: every stamp.
        odometry_label: where the odometry came from: ``synthetic``, or a real track's label
            (:class:`~locnerf.odometry.tracks.OdometryTrack`).
    """

    stamps: torch.Tensor
    truth: torch.Tensor
    odometry: torch.Tensor
    image_ticks: list[int]
    kidnap_tick: int | None
    path_times: torch.Tensor
    path: CameraPath
    odometry_valid: torch.Tensor | None = None
    odometry_label: str = "synthetic"

    def image(self, tick: int, generator: torch.Generator) -> torch.Tensor:
        """The image (H, W, 3) float32 in [0, 1] taken at index ``tick``."""
        metric_pose = self.path.poses_at(self.path_times[tick : tick + 1])[0]
        return self.path.image_at(float(self.path_times[tick]), metric_pose, generator)

    def depth(self, tick: int) -> DepthObservation | None:
        """The depth image (metres) taken with the image at index ``tick``; None without a depth camera."""
        return self.path.depth_at(float(self.path_times[tick]))


@dataclass(frozen=True)
class _Timeline:
    """The cheap per-stamp bookkeeping of a whole run: (K,) stamps and path times, image and kidnap indices."""

    stamps: torch.Tensor
    path_times: torch.Tensor
    image_ticks: list[int]
    kidnap_tick: int | None


def _timeline(path: CameraPath, config: ScenarioConfig) -> _Timeline:
    """Stamps on the odometry grid, the kidnapping's jump of the path time, the image stamps."""
    odom_rate = config.vio.rate
    if config.image_rate > odom_rate:
        raise LocnerfInputError(f"image rate {config.image_rate} Hz above the odometry rate {odom_rate} Hz: expected image_rate <= odom_rate")
    duration = config.duration if config.duration is not None else path.duration
    if config.kidnap_at is not None and config.kidnap_at >= duration:
        raise LocnerfInputError(f"kidnap_at {config.kidnap_at} s: expected a time inside the run (0, {duration}) s")
    count = math.floor(duration * odom_rate + 1e-9) + 1
    stamps = torch.arange(count, dtype=torch.float64) / odom_rate
    path_times = stamps.clone()
    kidnap_tick = None
    if config.kidnap_at is not None:
        kidnap_tick = max(1, math.ceil(config.kidnap_at * odom_rate - 1e-9))
        path_times[kidnap_tick:] += config.kidnap_shift if config.kidnap_shift is not None else path.kidnap_shift
    image_ticks: list[int] = []
    if config.image_rate > 0:
        image_times = path.image_times(config.image_rate, odom_rate, duration)
        image_ticks = sorted({round(float(t) * odom_rate) for t in image_times if round(float(t) * odom_rate) < count})
    return _Timeline(stamps, path_times, image_ticks, kidnap_tick)


def run_stamps(path: CameraPath, config: ScenarioConfig) -> torch.Tensor:
    """(K,) float64 odometry stamps of the whole run (what a real odometry track is sampled on)."""
    return _timeline(path, config).stamps


def run_times(path: CameraPath, config: ScenarioConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """(K,) float64 :func:`run_stamps`, and (K,) float64 the time along the path where the camera is at each
    (jumping at a kidnapping): which recorded frame it delivers there."""
    timeline = _timeline(path, config)
    return timeline.stamps, timeline.path_times


def check_timeline(path: CameraPath, config: ScenarioConfig) -> None:
    """Refuse now what simulating the run would refuse (rates, kidnapping time), e.g. before
    services that replay it are started.

    Raises:
        LocnerfInputError: naming the value and what was expected.
    """
    _timeline(path, config)


def scenario_segments(
    path: CameraPath, config: ScenarioConfig, normalization: MapNormalization, segment_ticks: int = SEGMENT_TICKS, track: OdometryTrack | None = None
) -> Iterator[TrackingScenario]:
    """The run as consecutive scenarios of at most ``segment_ticks`` stamps, simulated as they are asked for.

    Indices inside a segment (``image_ticks``, ``kidnap_tick``) count from its first stamp; the
    odometry and its noise draws continue from one segment to the next. With a real odometry
    ``track`` (on :func:`run_stamps`), its poses (the camera's, carried to the path's body) and its
    gaps replace the simulated odometry; ``config.vio`` then only sets the rate.

    Raises:
        ValueError: at once, not on iteration: an image rate above the odometry rate, a kidnapping
            outside the run, ``segment_ticks`` < 1, a track of another length, or a kidnapping with a
            track that did not come from the camera's own frames (a recorded file cannot see the jump).
    """
    if segment_ticks < 1:
        raise ValueError(f"segment_ticks {segment_ticks}: expected at least 1 stamp per segment")
    timeline = _timeline(path, config)
    if track is not None and len(track.poses) != len(timeline.stamps):
        raise LocnerfInputError(f"odometry {track.label}: {len(track.poses)} stamps for a run of {len(timeline.stamps)}; expected one pose or gap per stamp")
    if track is not None and timeline.kidnap_tick is not None and not track.from_camera:
        raise LocnerfInputError(
            f"odometry {track.label} with a kidnapping at {config.kidnap_at} s: a recorded trajectory follows the recorded camera and cannot"
            " see the simulated jump; expected the synthetic odometry or RGB-D odometry computed from the camera's frames (rgbd)"
        )
    return _simulate_segments(path, config, normalization, timeline, segment_ticks, track)


def _simulate_segments(
    path: CameraPath, config: ScenarioConfig, normalization: MapNormalization, timeline: _Timeline, segment_ticks: int, track: OdometryTrack | None
) -> Iterator[TrackingScenario]:
    """The segments of :func:`scenario_segments`, each simulated when it is asked for."""
    kidnap_tick = timeline.kidnap_tick
    to_body = pose_inverse(path.T_body_cam)
    generator = torch.Generator().manual_seed(config.seed)
    kidnap_correction: torch.Tensor | None = None  # (4, 4): from the jump on, the perceived pose is kidnap_correction · true pose
    last: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None  # perceived, body and odometry poses at the last stamp so far
    count = len(timeline.stamps)
    for begin in range(0, count, segment_ticks):
        end = min(count, begin + segment_ticks)
        metric = path.poses_at(timeline.path_times[begin:end])
        perceived = metric.clone()
        if kidnap_tick is not None and kidnap_tick < end:
            jump = max(kidnap_tick - begin, 0)
            if kidnap_correction is None:
                before = perceived[jump - 1] if jump > 0 else last[0]
                unseen = path.poses_at(timeline.stamps[kidnap_tick - 1 : kidnap_tick + 1])
                step = relative_pose(unseen[0], unseen[1])
                kidnap_correction = before @ step @ pose_inverse(metric[jump])
            perceived[jump:] = kidnap_correction @ metric[jump:]
        body = perceived @ to_body
        if track is not None:
            odometry = track.poses[begin:end] @ to_body
        elif last is None:
            odometry = simulate_odometry(body, config.vio, generator)
        else:
            odometry = simulate_odometry(torch.cat([last[1][None], body]), config.vio, generator, start=last[2])[1:]
        last = (perceived[-1], body[-1], odometry[-1])
        first_image, end_image = bisect.bisect_left(timeline.image_ticks, begin), bisect.bisect_left(timeline.image_ticks, end)
        yield TrackingScenario(
            stamps=timeline.stamps[begin:end],
            truth=normalization.metric_to_map(metric),
            odometry=odometry,
            image_ticks=[tick - begin for tick in timeline.image_ticks[first_image:end_image]],
            kidnap_tick=kidnap_tick - begin if kidnap_tick is not None and begin <= kidnap_tick < end else None,
            path_times=timeline.path_times[begin:end],
            path=path,
            odometry_valid=None if track is None else track.valid[begin:end],
            odometry_label="synthetic" if track is None else track.label,
        )


def build_scenario(path: CameraPath, config: ScenarioConfig, normalization: MapNormalization, track: OdometryTrack | None = None) -> TrackingScenario:
    """The whole run at once: its segments joined (see :func:`scenario_segments`)."""
    segments = list(scenario_segments(path, config, normalization, track=track))
    offsets = [0]
    for segment in segments[:-1]:
        offsets.append(offsets[-1] + len(segment.stamps))
    kidnaps = [offset + s.kidnap_tick for offset, s in zip(offsets, segments) if s.kidnap_tick is not None]
    return TrackingScenario(
        stamps=torch.cat([s.stamps for s in segments]),
        truth=torch.cat([s.truth for s in segments]),
        odometry=torch.cat([s.odometry for s in segments]),
        image_ticks=[offset + tick for offset, s in zip(offsets, segments) for tick in s.image_ticks],
        kidnap_tick=kidnaps[0] if kidnaps else None,
        path_times=torch.cat([s.path_times for s in segments]),
        path=path,
        odometry_valid=None if track is None else track.valid,
        odometry_label="synthetic" if track is None else track.label,
    )
