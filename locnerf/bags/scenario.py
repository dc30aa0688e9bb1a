"""A bag as the offline tracking experiment's run (``locnerf eval tracking --sequence BAG``).

The run walks the bag's odometry stamps (times from the first one); the truth at each is the bag's
ground truth interpolated along its geodesics (the bag needs a ground-truth topic); each image is
taken at the odometry stamp nearest to its own (within half an odometry period; the last image of a
stamp wins). The odometry is the bag's, not simulated. Every image is held in memory.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch

from locnerf.bags.events import bag_events
from locnerf.bags.topics import BagTopics
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.filter.depth_measurement import DepthObservation
from locnerf.geometry.se3 import interpolate_pose
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf.sim.scenario import TrackingScenario

logger = logging.getLogger(__name__)


class BagPath:
    """The bag's ground truth and images as a :class:`~locnerf.sim.paths.CameraPath` on the run's times (seconds from the first odometry).

    Args:
        truth_times: (G,) increasing seconds; truth: (G, 4, 4) float64 ``T_world_cam``, metric.
        images: time (seconds, an odometry stamp) -> image event.
    """

    def __init__(self, truth_times: np.ndarray, truth: torch.Tensor, images: dict[float, ImageEvent]) -> None:
        self.truth_times, self.truth, self.images = truth_times, truth, images
        self._intrinsics = next(iter(images.values())).intrinsics

    @property
    def duration(self) -> float:
        return float(self.truth_times[-1])

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        return self._intrinsics

    @property
    def T_body_cam(self) -> torch.Tensor:
        return torch.eye(4, dtype=torch.float64)

    @property
    def kidnap_shift(self) -> float:
        raise DatasetError("a bag's run cannot be kidnapped: its camera moved as recorded")

    def poses_at(self, times: torch.Tensor) -> torch.Tensor:
        """Ground truth (N, 4, 4) at ``times`` (N,), geodesically interpolated (held at the ends)."""
        stamps = self.truth_times
        out = []
        for time in torch.as_tensor(times, dtype=torch.float64).tolist():
            after = int(np.clip(np.searchsorted(stamps, time, side="right"), 1, len(stamps) - 1))
            span = stamps[after] - stamps[after - 1]
            fraction = float(np.clip((time - stamps[after - 1]) / span, 0.0, 1.0)) if span > 0 else 0.0
            out.append(interpolate_pose(self.truth[after - 1], self.truth[after], fraction))
        return torch.stack(out)

    def image_times(self, rate: float, odom_rate: float, duration: float) -> torch.Tensor:
        return torch.tensor(sorted(self.images), dtype=torch.float64)

    def image_at(self, time: float, pose: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        return torch.tensor(self.images[time].pixels, dtype=torch.float32) / 255.0

    def depth_at(self, time: float) -> DepthObservation | None:
        depth = self.images[time].depth
        if depth is None:
            return None
        metres = torch.from_numpy(depth.millimetres.astype(np.float32)) / 1000.0
        return DepthObservation(metres, depth.intrinsics, depth.T_cam_depth)


def bag_scenario(path: str | Path, normalization: MapNormalization, topics: BagTopics | None = None) -> TrackingScenario:
    """The bag's run (see the module), truth in the map frame of ``normalization``.

    Raises:
        DatasetError: a bag without ground truth, with fewer than two odometry messages or without an image.
    """
    odometry: list[OdometryEvent] = []
    truth: list[GroundTruthEvent] = []
    images: list[ImageEvent] = []
    for event in bag_events(path, topics):
        (odometry if isinstance(event, OdometryEvent) else truth if isinstance(event, GroundTruthEvent) else images).append(event)
    if len(odometry) < 2 or len(truth) < 2 or not images:
        raise DatasetError(
            f"bag {path}: {len(odometry)} odometry, {len(truth)} ground-truth and {len(images)} image messages read; "
            "the offline evaluation needs at least 2 odometry and 2 ground-truth messages (a ground-truth topic) and an image"
        )
    start = odometry[0].stamp
    stamps = np.array([event.stamp - start for event in odometry])
    truth_times = np.array([event.stamp - start for event in truth])
    order = np.argsort(truth_times, kind="stable")
    by_tick: dict[int, ImageEvent] = {}
    period = float(np.median(np.diff(stamps)))
    for image in images:
        tick = int(np.argmin(np.abs(stamps - (image.stamp - start))))
        if abs(stamps[tick] - (image.stamp - start)) <= period / 2:
            by_tick[tick] = image
    if len(by_tick) < len(images):
        logger.info("bag %s: %d of %d images taken (one per odometry stamp, within half a period)", path, len(by_tick), len(images))
    poses = torch.stack([truth[i].T_world_cam for i in order])
    bag_path = BagPath(truth_times[order], poses, {float(stamps[tick]): image for tick, image in by_tick.items()})
    times = torch.tensor(stamps, dtype=torch.float64)
    return TrackingScenario(
        stamps=times,
        truth=normalization.metric_to_map(bag_path.poses_at(times)),
        odometry=torch.stack([event.T_odom_body for event in odometry]),
        image_ticks=sorted(by_tick),
        kidnap_tick=None,
        path_times=times,
        path=bag_path,
    )
