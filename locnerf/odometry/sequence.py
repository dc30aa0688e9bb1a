"""The real odometry of a replayed sequence: which source, built on the run's stamps.

``synthetic`` leaves the simulator's odometry (:mod:`locnerf.sim.sensors`) in place; ``rgbd``
computes OpenCV RGB-D odometry (:mod:`locnerf.odometry.rgbd`) on the sequence's own frames, read
at the odometry's working size (:data:`ODOMETRY_DOWNSCALE`: 320×240 of a 640×480 Kinect) and fed
in the order and at the stamps the replay shows them; anything else names a trajectory file (TUM or
EuRoC) matched to the run's stamps (:func:`locnerf.odometry.tracks.file_track`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.geometry.validation import validate_pose_setting
from locnerf.odometry.rgbd import RgbdOdometryConfig
from locnerf.odometry.tracks import DEFAULT_MAX_GAP_S, OdometryTrack, file_track, rgbd_track
from locnerf.sim.events import ImageEvent, RgbdFrameEvent, posed_depth_frame, rgb8
from locnerf.sim.paths import SequencePath, bounce_order, read_sequence_frames

SYNTHETIC = "synthetic"
RGBD = "rgbd"
RGBD_ONLINE = "rgbd-online"
ODOMETRY_DOWNSCALE = 2
"""Colour size divisor of the frames the RGB-D odometry reads (7-Scenes: 320×240, its depth images' size)."""


class OdometrySourceConfig(BaseModel):
    """Where a replay's odometry comes from."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    source: str = Field(
        SYNTHETIC,
        description="'synthetic' (the simulator's, from the ground truth with drift and noise), 'rgbd' (OpenCV RGB-D odometry "
        "computed from the sequence's frames as they are replayed) or a TUM / EuRoC trajectory file matched to the images by stamp.",
    )
    file_format: str = Field("auto", description="Trajectory file: auto, tum or euroc.")
    max_gap: float = Field(DEFAULT_MAX_GAP_S, gt=0, description="Trajectory file: longest spacing of samples interpolated across, seconds.")
    T_body_cam: list[list[float]] | None = Field(
        None, description="Trajectory file: 4×4 pose of the camera (OpenGL axes) in the file's body frame, metres; None: the body is the camera."
    )
    rgbd: RgbdOdometryConfig = Field(default_factory=RgbdOdometryConfig, description="RGB-D odometry settings.")

    def model_post_init(self, context: object) -> None:
        if self.T_body_cam is not None:
            validate_pose_setting(self.T_body_cam, "odometry T_body_cam")

    def label(self, live: bool = False) -> str:
        """``synthetic``, ``rgbd`` (computed from the frames in order, offline), ``rgbd-online`` (computed
        by the ingest as the frames are released, ``live``) or ``file:<name>``, as every result names its odometry."""
        if self.source == SYNTHETIC:
            return SYNTHETIC
        return f"file:{Path(self.source).name}" if self.source != RGBD else RGBD_ONLINE if live else RGBD


@dataclass(frozen=True)
class RecordedReplay:
    """The recorded frames a replay of ``path`` shows: ``folder``'s ``split`` with the colour camera ``T_depth_colour``
    (4, 4, map units; None: the data set's own) in ``passes`` passes, as the path was read (the colour on the data set's own
    camera model even for a map that records a lens: on the kitchen's SfM-built maps the odometry erred more through the lens,
    docs/RESULTS.md)."""

    path: SequencePath
    folder: str | Path
    split: str
    T_depth_colour: torch.Tensor | None = None
    passes: int = 1

    def frames(self) -> PosedImages:
        """The split's frames at the odometry's working size (:data:`ODOMETRY_DOWNSCALE`)."""
        return read_sequence_frames(self.folder, self.split, ODOMETRY_DOWNSCALE, T_depth_colour=self.T_depth_colour)

    def shown(self, stamps: torch.Tensor, path_times: torch.Tensor | None, count: int) -> list[int]:
        """The split's frame (of ``count``) the camera delivers at each of ``stamps`` (K,), where it is at ``path_times``
        (K,) along the path (None: the stamps) (:func:`_replayed_frames`)."""
        return _replayed_frames(self.path, stamps if path_times is None else path_times, count, self.passes)


def sequence_track(config: OdometrySourceConfig, replay: RecordedReplay, stamps: torch.Tensor, path_times: torch.Tensor | None = None) -> OdometryTrack | None:
    """The real odometry on ``stamps`` (K,) of ``replay``; None for ``synthetic``. ``rgbd`` reads the frame the
    camera delivers at ``path_times`` (K,) along the path (a kidnapping's jump included; None: the stamps), as a
    robot's own odometry would see them.

    Raises:
        LocnerfInputError: ``rgbd`` on a replay not at the capture's frame rate (its stamps fall between frames), or
            past the replay's last frame.
        FileNotFoundError / DatasetError: an unreadable or malformed trajectory file (file and line
            named), one whose stamps never overlap the run's, or frames without depth for ``rgbd``.
    """
    if config.source == SYNTHETIC:
        return None
    if config.source != RGBD:
        extrinsic = None if config.T_body_cam is None else torch.tensor(config.T_body_cam, dtype=torch.float64)
        return file_track(config.source, stamps, config.file_format, extrinsic, config.max_gap)
    frames = replay.frames()
    return rgbd_track(frames, replay.shown(stamps, path_times, len(frames)), stamps, config.rgbd)


def sequence_rgbd_frames(replay: RecordedReplay, stamps: torch.Tensor, path_times: torch.Tensor | None = None) -> Iterator[RgbdFrameEvent]:
    """The RGB-D frames the camera of ``replay`` delivers at ``stamps`` (K,), where it is at ``path_times`` (K,) along
    the path (a kidnapping's jump included; None: the stamps), for odometry computed online
    (services/sensor_ingest/odometry_stage.py): colour and depth read as :func:`sequence_track` reads them,
    8-bit colour and millimetre depth as sent. Read at once, each event made as it is asked for.

    Raises:
        LocnerfInputError: a replay not at the capture's frame rate, or past its last frame; DatasetError: frames without depth.
    """
    frames = replay.frames()
    if frames.depths is None or frames.depth_intrinsics is None:
        raise DatasetError(f"{frames.source}: RGB-D odometry needs depth images, and these frames have none")
    indices = replay.shown(stamps, path_times, len(frames))
    return (
        RgbdFrameEvent(stamp, ImageEvent(stamp, rgb8(frames.images[index]), frames.intrinsics, posed_depth_frame(frames, index)))
        for stamp, index in zip(stamps.tolist(), indices)
    )


def _replayed_frames(path: SequencePath, stamps: torch.Tensor, count: int, passes: int) -> list[int]:
    """The split's frame shown at each of ``stamps`` (path times) by a replay of ``count`` frames in ``passes`` passes.

    Raises:
        LocnerfInputError: a time past the replay's last frame (it would wrap to the first), or between frames.
    """
    order = bounce_order(count, passes)  # the replay's frames as positions in the split, never copied
    last = path.duration - path.frame_period
    if len(stamps) and float(stamps.max()) > last + 1e-9:
        raise LocnerfInputError(
            f"RGB-D odometry: the replayed camera reaches path time {float(stamps.max()):.3f} s, past its last frame at {last:.3f} s, where the"
            f" replay would jump back to its first frame (a jump no camera makes); expected a shorter run or an earlier or smaller kidnapping,"
            f" or --passes {passes + 1} or more to replay the frames forward and backward"
        )
    try:
        return [order[path.frame_at(float(stamp))] for stamp in stamps]
    except ValueError as error:
        raise LocnerfInputError(f"RGB-D odometry needs the replay at the capture's frame rate (--frame-rate): {error}") from error
