"""A filter loop driven without a transport: a fake clock, workers answering on demand, and the payloads it is fed."""

from __future__ import annotations

import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import SearchRegion
from locnerf.messages import keys
from locnerf.messages.codec import decode, encode, encode_image
from locnerf.messages.schemas import ImageHeader, InitialPoseCommand, Odometry, PoseEstimate, UpdateRequest
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.service import FilterLoop, FilterLoopConfig
from locnerf_services.nerf_worker.service import NerfWorker
from locnerf_services.sensor_ingest.service import event_message

ROBOT = "r"


class Harness:
    """A filter loop, a fake clock and workers answering on demand."""

    def __init__(self, world: ProceduralWorld, config: FilterLoopConfig = FilterLoopConfig(), seed: int = 0, localizer_config=None, keyframes=None) -> None:
        bounds = world.camera_bounds()
        self.region = SearchRegion(low=tuple(bounds[0].tolist()), high=tuple(bounds[1].tolist()))
        self.now = 0.0
        settings = localizer_config if localizer_config is not None else preset("llff")
        localizer = Localizer(settings, torch.Generator().manual_seed(seed), region=self.region, keyframes=keyframes)
        self.loop = FilterLoop(ROBOT, localizer, world.normalization, self.region, config, lambda: self.now, world.checksum)
        self.world = world
        self.requests: list[tuple[str, UpdateRequest]] = []
        self.poses: list[PoseEstimate] = []

    def add_worker(self, name: str, alive: bool = True, map_checksum: str | None = None) -> None:
        """Worker ``name``'s token appears (or vanishes with ``alive`` false), announcing the world's map or ``map_checksum``."""
        token = keys.key(ROBOT, keys.WORKER_ALIVE, worker_id=name, device="cpu", map_checksum=map_checksum or self.world.checksum)
        self.collect(self.loop.worker_changed(token, alive))

    def collect(self, outgoing) -> None:
        for key, payload in outgoing:
            if "/update/request/" in key:
                self.requests.append((key.rsplit("/", 1)[1], decode(payload, UpdateRequest)))
            elif key.endswith("filter/pose"):
                self.poses.append(decode(payload, PoseEstimate))

    def answer(self, request: UpdateRequest) -> None:
        self.collect(self.loop.handle_result(encode(NerfWorker(self.world, "w").handle(request))))

    def feed(self, event) -> None:
        key, payload = event_message(ROBOT, event)
        self.collect(self.loop.handle_odometry(payload) if key.endswith("odom") else self.loop.handle_image(payload))

    def tick(self) -> None:
        self.collect(self.loop.tick())

    def start_at(self, truth: torch.Tensor, covariance: torch.Tensor) -> None:
        """Initialise around ``truth`` (4, 4) with ``covariance`` (6, 6), take odometry at 0 s and apply its prediction."""
        self.loop.handle_initial_pose(encode(InitialPoseCommand(stamp=0.0, T_world_cam=truth.tolist(), covariance=covariance.tolist())))
        self.collect(self.loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
        self.loop.predict_pending()


def odometry_payload(stamp: float, pose: torch.Tensor) -> bytes:
    """An Odometry message of ``pose`` (4, 4) at ``stamp``."""
    return encode(Odometry(stamp=stamp, T_odom_body=pose.tolist()))


def image_payload(world: ProceduralWorld, stamp: float, pose: torch.Tensor) -> bytes:
    """An image frame of the world seen from ``pose`` at ``stamp``, in its default camera."""
    pixels = (world.render_image(pose) * 255).round().to(torch.uint8).numpy()
    intrinsics = world.default_intrinsics
    header = ImageHeader(stamp=stamp, encoding="rgb8", width=intrinsics.width, height=intrinsics.height, intrinsics=intrinsics)
    return encode_image(header, pixels)
