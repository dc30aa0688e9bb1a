"""Tiny seeded sensor streams and the bags the tests write from them (with rosbags' writer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from locnerf.bags.writer import BagWriter, EventWriter
from locnerf.geometry.se3 import se3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import DepthFrame, GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent

COLOUR = PinholeIntrinsics(fx=14.0, fy=15.0, cx=7.5, cy=5.25, width=16, height=12)
DEPTH = PinholeIntrinsics(fx=11.0, fy=11.5, cx=5.0, cy=4.0, width=10, height=8)
ODOMETRY_RATE = 10.0
BASE_NS = 1_700_000_000_123_456_789
"""A stamp near 2023 in whole nanoseconds: the events' stamps are BASE_NS · 1e-9 + k / rate."""


def random_pose(generator: torch.Generator, scale: float = 1.0) -> torch.Tensor:
    return se3_exp(scale * torch.randn(6, generator=generator, dtype=torch.float64))


def sensor_stream(seed: int = 0, ticks: int = 12, image_every: int = 3, depth: str = "unregistered") -> list[SensorEvent]:
    """Ground truth and odometry on every tick, then an image every ``image_every`` ticks, with a
    depth image (``unregistered``: own camera and offset; ``registered``: the colour camera's; ``none``)."""
    generator = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    offset = random_pose(generator, 0.05)
    events: list[SensorEvent] = []
    for tick in range(ticks):
        stamp = (BASE_NS + round(tick * 1e9 / ODOMETRY_RATE)) * 1e-9
        events.append(GroundTruthEvent(stamp, random_pose(generator)))
        events.append(OdometryEvent(stamp, random_pose(generator)))
        if tick % image_every:
            continue
        pixels = rng.integers(0, 256, (COLOUR.height, COLOUR.width, 3), dtype=np.uint8)
        frame = None
        if depth == "unregistered":
            frame = DepthFrame(rng.integers(0, 5000, (DEPTH.height, DEPTH.width)).astype(np.uint16), DEPTH, offset)
        elif depth == "registered":
            frame = DepthFrame(rng.integers(0, 5000, (COLOUR.height, COLOUR.width)).astype(np.uint16), COLOUR)
        events.append(ImageEvent(stamp, pixels, COLOUR, frame))
    return events


def write_events(path: Path, events: list[SensorEvent], storage: str = "mcap", compression: str = "") -> Path:
    """The events as a bag (the export's writer)."""
    with BagWriter(path, storage) as bag:
        writer = EventWriter(bag, compression=compression)
        for event in events:
            writer.write(event)
    return path
