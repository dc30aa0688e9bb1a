"""``locnerf view``: watch a running system in rerun: the map, the particles, the poses, the camera, the figures.

It subscribes to the robot's topics (:mod:`locnerf_cli.view_bus`) and logs what arrives to rerun
(:mod:`locnerf_cli.view_rerun`): into a spawned viewer, into a ``.rrd`` recording (``--save``, which
needs no display; open it later with ``rerun run.rrd``), or both. The map is drawn as its occupied
voxels (:mod:`locnerf.maps.cloud`) from ``--map``, or from the procedural world when the filter's
status names the world's checksum. Once a second (``--image-hz``) the newest camera image is shown
beside the map rendered at the newest estimate, at a small size (``--image-width``), on the CPU.

rerun is an optional extra (``pip install 'locnerf[view]'``).
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import torch

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import RadianceMap
from locnerf.maps.cloud import map_cloud
from locnerf.maps.source import WORLD, open_map
from locnerf.messages import keys
from locnerf.messages.schemas import FilterStatus, ImageHeader, ParticleCloud, PoseEstimate, PoseStamped
from locnerf.render.image import render_image
from locnerf.sim.world import ProceduralWorld
from locnerf_cli.bus_client import add_bus_arguments, open_cli_bus
from locnerf_cli.monitor import GroundTruthMatcher
from locnerf_cli.view_bus import ViewFeed

logger = logging.getLogger(__name__)

INSTALL_HINT = "pip install 'locnerf[view]'"
TRAJECTORY_POINTS = 20_000
"""Longest path drawn (the newest positions)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf view``."""
    parser.add_argument("--map", help=f"'{WORLD}' or the map file the services run on (default: the world when the filter runs on it, else no map)")
    parser.add_argument("--save", type=Path, help="write the recording to this .rrd file (no viewer is opened unless --spawn is given too)")
    parser.add_argument("--spawn", action="store_true", help="open the rerun viewer (the default without --save)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C or SIGTERM)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many poses (0: no limit)")
    parser.add_argument("--image-hz", type=float, default=1.0, help="rate of the camera image and of the render at the estimate (0: none)")
    parser.add_argument("--image-width", type=int, default=160, help="width of the camera image and the render, pixels")
    parser.add_argument("--trajectory-hz", type=float, default=2.0, help="rate at which the drawn paths are updated")
    add_bus_arguments(parser)
    parser.set_defaults(func=run)


def check_save_path(save: Path | None) -> None:
    """Refuse a ``--save`` path that rerun could not create.

    Raises:
        LocnerfInputError: ``save`` is a folder or its folder does not exist.
    """
    if save is not None and (save.is_dir() or not save.parent.is_dir()):
        raise LocnerfInputError(f"--save {save}: expected a file in an existing folder (the .rrd recording)")


def import_rerun() -> ModuleType:
    """:mod:`locnerf_cli.view_rerun`, which needs the optional rerun-sdk.

    Raises:
        LocnerfInputError: rerun-sdk is not installed, with the command that installs it.
    """
    if importlib.util.find_spec("rerun") is None:
        raise LocnerfInputError(f"locnerf view needs rerun-sdk, an optional extra: {INSTALL_HINT}")
    import locnerf_cli.view_rerun as view_rerun

    return view_rerun


class Periodic:
    """True at most ``hz`` times a second (never when ``hz`` is 0)."""

    def __init__(self, hz: float) -> None:
        self.period = 1.0 / hz if hz > 0 else float("inf")
        self.last = -float("inf")

    def due(self, now: float) -> bool:
        """Whether a period has passed since the last :meth:`done`."""
        return now - self.last >= self.period

    def done(self, now: float) -> None:
        self.last = now


class View:
    """What the view remembers between messages, and where each message goes.

    Args:
        log: :mod:`locnerf_cli.view_rerun`; recording: its open recording.
        args: the command's arguments.
    """

    def __init__(self, log: ModuleType, recording, args: argparse.Namespace) -> None:
        self.log, self.recording, self.args = log, recording, args
        self.radiance_map: RadianceMap | None = None
        self.matcher = GroundTruthMatcher()
        self.paths: dict[str, list[tuple[float, float, float]]] = {"estimate": [], "truth": []}
        self.latest: PoseEstimate | None = None
        self.poses = 0
        self.cameras_logged = False
        self.frustum = 0.15
        """Distance of the drawn image plane from the camera centre, metres (a thirtieth of the map once it is known)."""
        self.map_noted = False

    def show_map(self, radiance_map: RadianceMap) -> None:
        """Draw the map's occupied voxels and keep it for renders."""
        self.radiance_map = radiance_map
        self.map_noted = True
        started = time.monotonic()
        try:
            cloud = map_cloud(radiance_map)
        except LocnerfInputError as error:
            logger.warning("no point cloud of the map: %s", error)
            return
        self.log.log_map(self.recording, cloud)
        self.frustum = float((cloud.points.amax(0) - cloud.points.amin(0)).max()) / 30
        logger.info("map: %d occupied voxels of %.3f m in %.1f s", len(cloud.points), cloud.voxel, time.monotonic() - started)

    def on_status(self, status: FilterStatus) -> None:
        self.log.log_status(self.recording, status)
        if self.radiance_map is None and not self.map_noted:
            self.map_noted = True
            if status.map_checksum == ProceduralWorld.default().checksum:
                self.show_map(open_map(WORLD, torch.device("cpu")))
            else:
                logger.warning("the filter's map (checksum %s…) is not the world: give it with --map to see it", status.map_checksum[:12])

    def on_pose(self, estimate: PoseEstimate) -> None:
        error = self.matcher.error(estimate)
        self.log.log_estimate(self.recording, estimate, None if error is None else (error.translation, error.rotation_deg))
        self.paths["estimate"].append(tuple(row[3] for row in estimate.T_world_cam[:3]))
        self.latest = estimate
        self.poses += 1

    def on_truth(self, truth: PoseStamped) -> None:
        self.matcher.add_truth(truth)
        self.log.log_truth(self.recording, truth)
        self.paths["truth"].append(tuple(row[3] for row in truth.T_world_cam[:3]))

    def on_particles(self, cloud: ParticleCloud) -> None:
        self.log.log_particles(self.recording, cloud)

    def draw_paths(self) -> None:
        """The paths so far (the newest TRAJECTORY_POINTS), stamped with the newest pose."""
        if self.latest is None:
            return
        for which, path in self.paths.items():
            del path[:-TRAJECTORY_POINTS]
            if len(path) >= 2:
                self.log.log_trajectory(self.recording, which, self.latest.stamp_ns, np.asarray(path, dtype=np.float32))

    def on_image(self, header: ImageHeader, pixels: np.ndarray) -> None:
        """The camera image at ``--image-width`` and the map rendered there at the newest estimate."""
        intrinsics = header.intrinsics.scaled(self.args.image_width / header.width)
        camera = cv2.resize(pixels, (intrinsics.width, intrinsics.height), interpolation=cv2.INTER_AREA)
        if not self.cameras_logged:
            self.log.log_cameras(self.recording, intrinsics, plane=self.frustum)
            self.cameras_logged = True
        render = None
        if self.radiance_map is not None and self.latest is not None:
            pose = self.radiance_map.normalization.metric_to_map(torch.tensor(self.latest.T_world_cam, dtype=torch.float64))
            image = render_image(self.radiance_map.render_rays, pose.to(self.radiance_map.device, torch.float32), intrinsics)
            render = (image.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
        self.log.log_images(self.recording, header.stamp_ns, camera, render)


def _stop_on_sigterm() -> threading.Event:
    """An event set by SIGTERM (how ``locnerf up`` and supervisors stop the view)."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda _signum, _frame: stop.set())
    return stop


def _handlers(view: View) -> dict[str, Callable]:
    return {"pose": view.on_pose, "truth": view.on_truth, "particles": view.on_particles, "status": view.on_status}


def run(args: argparse.Namespace) -> int:
    if args.count < 0 or args.duration < 0 or args.image_width < 8:
        raise LocnerfInputError(f"--count {args.count}, --duration {args.duration}, --image-width {args.image_width}: expected >= 0, >= 0, >= 8")
    check_save_path(args.save)
    stop = _stop_on_sigterm()
    log = import_rerun()
    radiance_map = open_map(args.map, torch.device("cpu")) if args.map else None
    recording = log.open_recording(args.save, spawn=args.spawn or args.save is None)
    bus = open_cli_bus(args.connect)
    feed = ViewFeed(bus, args.robot_id)
    view = View(log, recording, args)
    handlers = _handlers(view)
    deadline = time.monotonic() + args.duration if args.duration > 0 else float("inf")
    images, paths = Periodic(args.image_hz), Periodic(args.trajectory_hz)
    ready = None
    try:
        with recording:
            if radiance_map is not None:
                view.show_map(radiance_map)
            ready = bus.declare_token(keys.key(args.robot_id, keys.VIEW_ALIVE))  # `locnerf up --view` starts the services after this
            while not stop.is_set() and time.monotonic() < deadline and (args.count == 0 or view.poses < args.count):
                item = feed.next(timeout=0.05)
                if item is not None:
                    handlers[item[0]](item[1])
                now = time.monotonic()
                if images.due(now) and (frame := feed.take_image()) is not None:
                    view.on_image(*frame)
                    images.done(now)
                if paths.due(now):
                    view.draw_paths()
                    paths.done(now)
            view.draw_paths()
    except KeyboardInterrupt:
        pass
    finally:
        if ready is not None:
            ready.close()
        feed.close()
        bus.close()
    logger.info("view: %d poses logged, %d bad messages, %d dropped", view.poses, feed.bad_messages, feed.dropped)
    return 0
