"""Camera paths a simulated run follows: the procedural world's figure-eight or a posed image sequence.

- :class:`WorldPath`: the figure-eight of :mod:`locnerf.sim.trajectory` in the procedural world,
  images rendered at the true camera pose with the simulated camera's noise and gain; the camera
  sits on the body at ``CameraConfig.T_body_cam``.
- :class:`SequencePath`: a posed image sequence (e.g. the lego test orbit). Frame ``j`` gets the
  stamp ``j · Δ``, where ``Δ`` is either the mean distance between consecutive frames divided by
  the nominal speed, rounded to a whole number of odometry periods (so every frame lies on the
  grid), or the period of the capture's own frame rate (a recorded video replayed at its real
  speed; then the odometry period must be a whole number of frames); between frames the pose
  follows the SE(3) geodesic. The sequence is treated as a closed loop, and the camera is the body.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Protocol

import torch

from locnerf.data import PosedImages, read_nerf_synthetic
from locnerf.data.colour_camera import metric_offset, with_colour_camera
from locnerf.data.detect import dataset_format, read_dataset
from locnerf.data.map_lens import MapLens
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.filter.depth_measurement import DepthObservation
from locnerf.geometry import relative_pose, se3_exp, se3_log
from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.sensors import CameraConfig, observe_image
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld


class CameraPath(Protocol):
    """A closed camera path with an image for every pose the run asks for."""

    @property
    def duration(self) -> float:
        """Length of one loop, seconds."""

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        """The camera of the images."""

    @property
    def T_body_cam(self) -> torch.Tensor:
        """(4, 4) float64 pose of the camera in the body whose motion the odometry reports."""

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        """True ``T_world_cam`` (N, 4, 4) float64, metric data-set frame, at times (N,) seconds."""

    @property
    def kidnap_shift(self) -> float:
        """How far along the path (seconds) a kidnapping moves the camera: about half a loop."""

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        """(I,) float64 stamps on the odometry grid where images are taken, about ``rate`` per second."""

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Image (H, W, 3) float32 in [0, 1] seen at path time ``time`` from ``pose`` (4, 4)."""

    def depth_at(self, time: float) -> DepthObservation | None:
        """The depth image (metres) taken with the image at path time ``time``; None without a depth camera."""


def _grid_times(rate: float, odom_rate: float, duration: float) -> torch.Tensor:
    """Stamps about ``rate`` per second, each rounded to the odometry grid, without repeats."""
    count = math.floor(duration * rate + 1e-9) + 1
    ticks = torch.round(torch.arange(count, dtype=torch.float64) / rate * odom_rate)
    return torch.unique(ticks) / odom_rate


class WorldPath:
    """The figure-eight through the procedural world: the trajectory is the body's, the camera is
    mounted on it at ``camera.T_body_cam``.

    Raises:
        InvalidPoseError: ``camera.T_body_cam`` is not a rigid transform.
    """

    def __init__(self, world: ProceduralWorld, trajectory: FigureEightTrajectory, camera: CameraConfig) -> None:
        self.world = world
        self.trajectory = trajectory
        self.camera = camera
        self._T_body_cam = torch.tensor(camera.T_body_cam, dtype=torch.float64)
        validate_poses(self._T_body_cam, name="camera.T_body_cam")

    @property
    def duration(self) -> float:
        return self.trajectory.duration

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        return self.world.default_intrinsics

    @property
    def kidnap_shift(self) -> float:
        return self.trajectory.duration / 2

    @property
    def T_body_cam(self) -> torch.Tensor:
        return self._T_body_cam

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        return self.trajectory.poses_at(times) @ self._T_body_cam

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        return _grid_times(rate, odom_rate, duration)

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        return observe_image(self.world.render_image, pose, time, self.intrinsics, self.camera, generator)

    def depth_at(self, time: float) -> DepthObservation | None:
        return None  # the simulated camera is RGB only


class SequencePath:
    """A posed image sequence replayed as a closed loop at a nominal speed.

    Args:
        frames: the sequence's images and poses (map frame of its data set, metric).
        speed: nominal camera speed, data-set units per second (ignored when ``frame_rate`` is given).
        odom_rate: odometry rate, Hz; frame stamps are whole multiples of its period.
        frame_rate: the capture's frame rate, Hz, to replay the frames at their real speed (e.g. 30
            for 7-Scenes' Kinect); it must be a whole multiple of ``odom_rate``, so that every odometry
            stamp, and so every image, falls on a frame. None: frames are spaced by ``speed``.
    """

    def __init__(self, frames: PosedImages, speed: float, odom_rate: float, frame_rate: float | None = None) -> None:
        if len(frames) < 2:
            raise DatasetError(f"{frames.source}: {len(frames)} frame(s), expected at least 2 to follow a path")
        if speed <= 0:
            raise ValueError(f"speed {speed}: expected a positive nominal speed (units per second)")
        self.frames = frames
        poses = frames.T_world_cam.double()
        if frame_rate is None:
            steps = (poses[1:, :3, 3] - poses[:-1, :3, 3]).norm(dim=-1)
            self.frame_period = max(1, round(float(steps.mean()) / speed * odom_rate)) / odom_rate
        else:
            frames_per_tick = frame_rate / odom_rate
            if frame_rate <= 0 or round(frames_per_tick) < 1 or abs(frames_per_tick - round(frames_per_tick)) > 1e-9:
                raise LocnerfInputError(f"frame rate {frame_rate} Hz: expected a whole multiple of the odometry rate {odom_rate} Hz")
            self.frame_period = 1.0 / frame_rate
        closed = torch.cat([poses, poses[:1]])
        self._tangents = se3_log(relative_pose(closed[:-1], closed[1:]))  # (K, 6) frame j -> j + 1

    @property
    def duration(self) -> float:
        return len(self.frames) * self.frame_period

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        return self.frames.intrinsics

    @property
    def kidnap_shift(self) -> float:
        return (len(self.frames) // 2) * self.frame_period

    @property
    def T_body_cam(self) -> torch.Tensor:
        return torch.eye(4, dtype=torch.float64)

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        phase = torch.remainder(torch.as_tensor(times, dtype=torch.float64) / self.frame_period, len(self.frames))
        index = phase.floor().long().clamp(max=len(self.frames) - 1)
        fraction = (phase - index)[:, None]
        return self.frames.T_world_cam.double()[index] @ se3_exp(fraction * self._tangents[index])

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        if rate * self.frame_period > 1.0 + 1e-9:
            raise LocnerfInputError(
                f"image rate {rate} Hz above the sequence's {1.0 / self.frame_period:.4g} frames per second: expected at most one image per frame "
                "(a faster replay, --speed or --frame-rate, gives more frames per second)"
            )
        stride = max(1, round(1.0 / (rate * self.frame_period)))
        count = math.floor(duration / (stride * self.frame_period) + 1e-9) + 1
        return torch.arange(count, dtype=torch.float64) * stride * self.frame_period

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        return self.frames.images[self.frame_at(time)]

    def depth_at(self, time: float) -> DepthObservation | None:
        if self.frames.depths is None or self.frames.depth_intrinsics is None:
            return None
        return DepthObservation(self.frames.depths[self.frame_at(time)], self.frames.depth_intrinsics, self.frames.T_cam_depth)

    def frame_at(self, time: float) -> int:
        """The frame taken at path time ``time`` (a frame stamp)."""
        phase = time / self.frame_period
        index = round(phase)
        if abs(phase - index) > 1e-6:
            raise ValueError(f"image time {time} s is between frames (period {self.frame_period} s): expected a frame stamp")
        return index % len(self.frames)


def bounce_order(count: int, passes: int) -> list[int]:
    """Frame positions of ``passes`` replays of ``count`` frames, forward and backward in turn, each
    turn sharing its end frame with the pass before: ``[0 .. n-1, n-2 .. 0, 1 .. n-1, ...]``
    (``count + (passes - 1)·(count - 1)`` frames).

    Raises:
        LocnerfInputError: ``passes`` < 1 or fewer than 2 frames with more than one pass.
    """
    if passes < 1 or (passes > 1 and count < 2):
        raise LocnerfInputError(f"{passes} passes over {count} frames: expected at least 1 pass (and 2 frames to turn back)")
    order = list(range(count))
    for turn in range(1, passes):
        order += list(range(count - 2, -1, -1)) if turn % 2 else list(range(1, count))
    return order


def read_sequence_frames(
    folder: str | Path,
    split: str,
    downscale: int | None,
    background: str = "white",
    T_depth_colour: torch.Tensor | None = None,
    passes: int = 1,
    poses: str = "dslam",
    lens: MapLens | None = None,
) -> PosedImages:
    """A data-set folder's ``split`` (any format of :func:`locnerf.data.read_dataset`) in metres, the
    poses moved onto the colour camera ``T_depth_colour`` (4, 4, map units) when given, replayed
    ``passes`` times forward and backward (:func:`bounce_order`); ``poses``: 7-Scenes' ground truth
    (``dslam`` | ``sfm``, :mod:`locnerf.data.sfm_poses`; with ``sfm`` the poses are the colour camera's
    and ``T_depth_colour`` places the depth camera); ``lens``: the colour images resampled through the lens
    an SfM map records onto its camera (:class:`locnerf.data.map_lens.MapLens`), as the map's queries are."""
    if dataset_format(folder) == "nerf_synthetic":
        frames = read_nerf_synthetic(folder, split=split, background=background, downscale=downscale or 1)
    else:
        frames = read_dataset(folder, split=split, downscale=downscale, poses=poses, T_depth_colour=T_depth_colour if poses == "sfm" else None)
    if T_depth_colour is not None and frames.T_cam_depth is None:
        frames = with_colour_camera(frames, T_depth_colour)
    if lens is not None:
        frames = lens.apply(frames)
    if passes != 1:
        frames = frames.subset(bounce_order(len(frames), passes))
    depths = frames.depths / frames.normalization.scale if frames.depths is not None else None
    T_world_cam = frames.normalization.map_to_metric(frames.T_world_cam.double())
    return dataclasses.replace(frames, T_world_cam=T_world_cam, depths=depths, T_cam_depth=metric_offset(frames))


def read_sequence_path(
    folder: str | Path,
    split: str,
    downscale: int | None,
    speed: float,
    odom_rate: float,
    background: str = "white",
    frame_rate: float | None = None,
    T_depth_colour: torch.Tensor | None = None,
    passes: int = 1,
    poses: str = "dslam",
    lens: MapLens | None = None,
) -> SequencePath:
    """A data-set folder's ``split`` (any format of :func:`locnerf.data.read_dataset`) as a
    :class:`SequencePath`, poses (and depth images, where the data set has them) in the data set's metric frame.

    ``downscale`` None is the reader's default; ``background`` is the colour NeRF-synthetic RGBA
    frames are composited on (other formats have none); ``frame_rate`` replays the frames at the
    capture's own rate instead of ``speed``; ``T_depth_colour`` (4, 4, map units), the colour camera
    the map was built for (:mod:`locnerf.data.colour_camera`), moves the poses onto it; ``passes`` > 1
    replays the frames forward and backward in turn (:func:`bounce_order`); ``poses`` and ``lens`` as :func:`read_sequence_frames`.
    """
    return SequencePath(read_sequence_frames(folder, split, downscale, background, T_depth_colour, passes, poses, lens), speed, odom_rate, frame_rate)
