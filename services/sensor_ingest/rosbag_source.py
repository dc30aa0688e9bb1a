"""The ``rosbag`` source: a ROS 2 bag's odometry, camera and ground-truth topics replayed as the sensor stream.

The bag is read with rosbags (MCAP or SQLite3; :mod:`locnerf.bags`), its messages translated as the
ROS 2 node translates them (undistorted images on their CameraInfo's camera, depth images paired by
stamp) and released by the ingest's pacer at their header stamps: ``speed = 1`` replays in real time,
2 twice as fast, 0 as fast as the ingest can send. Bad messages are counted in the ingest's status
(``bad_<kind>``) and skipped; progress is logged every ``progress_every`` seconds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator

import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

from locnerf.bags.events import bag_events
from locnerf.bags.topics import BagTopics
from locnerf.errors import ConfigError
from locnerf.geometry.validation import validate_pose_setting
from locnerf.sim.events import SensorEvent

logger = logging.getLogger(__name__)


class RosbagSourceConfig(BaseModel):
    """Which bag to replay and which of its topics."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: str = Field("", description="rosbag2 folder (metadata.yaml) or an .mcap / .db3 file.")
    topics: BagTopics = Field(default_factory=BagTopics, description="Topic names (defaults: /odom, /camera/image_raw, ...; docs/BAGS.md).")
    T_body_cam: list[list[float]] | None = Field(
        None,
        description="4×4 pose of the camera (OpenGL axes) in the body, applied to the ground truth (of the body) so that it is the camera's; "
        "None: identity (the filter's loop.T_body_cam should be the same).",
    )
    progress_every: float = Field(5.0, gt=0, description="Wall seconds between progress log lines.")

    @field_validator("T_body_cam")
    @classmethod
    def _rigid(cls, value: list[list[float]] | None) -> list[list[float]] | None:
        return None if value is None else validate_pose_setting(value, "rosbag.T_body_cam")


class BagProgress:
    """Logs ``done / total`` messages read at most every ``every`` wall seconds, and at the end."""

    def __init__(self, path: str, every: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.path, self.every, self.clock = path, every, clock
        self.next_log = clock() + every

    def __call__(self, done: int, total: int) -> None:
        if done == total or self.clock() >= self.next_log:
            self.next_log = self.clock() + self.every
            logger.info("bag %s: %d / %d messages read (%.0f %%)", self.path, done, total, 100.0 * done / max(total, 1))


def rosbag_events(config: RosbagSourceConfig, record: Callable[[str, str], None]) -> Iterator[SensorEvent]:
    """The bag's sensor events; bad messages reach ``record(kind, reason)``.

    Raises:
        ConfigError: no path.
    """
    if not config.path:
        raise ConfigError("source = 'rosbag' needs rosbag.path: the bag folder or .mcap / .db3 file")
    T_body_cam = None if config.T_body_cam is None else torch.tensor(config.T_body_cam, dtype=torch.float64)
    return bag_events(config.path, config.topics, T_body_cam, record, BagProgress(config.path, config.progress_every))
