"""The ingest's progress line: counts, rates over the last interval and the sensor time reached."""

from __future__ import annotations

import logging

import numpy as np
import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import ImageEvent, OdometryEvent
from locnerf_services.sensor_ingest.service import ProgressLog

INTRINSICS = PinholeIntrinsics(fx=10.0, fy=10.0, cx=1.5, cy=1.5, width=4, height=4)


def test_progress_lines_report_counts_and_rates_once_per_interval(caplog):
    wall = [100.0]
    progress = ProgressLog(10.0, clock=lambda: wall[0])
    events = []
    for index in range(90):  # 15 Hz stamps, every third event a frame, sent 4 per wall second
        stamp = index / 15.0
        events.append(
            ImageEvent(stamp, np.zeros((4, 4, 3), np.uint8), INTRINSICS) if index % 3 == 0 else OdometryEvent(stamp, torch.eye(4, dtype=torch.float64))
        )
    with caplog.at_level(logging.INFO, logger="locnerf_services.sensor_ingest.service"):
        for event in events:
            wall[0] += 0.25
            progress.sent(event)
    lines = [record.getMessage() for record in caplog.records]
    # Lines fall due at 10 s and 20 s (40 and 80 events); the 90th event is at 22.5 s.
    assert len(lines) == 2, lines
    assert lines[0].startswith("ingest: 40 events sent (14 frames) in 10 s; last 10 s: 4.0 events/s, 1.40 frames/s; sensor time 2.6 s"), lines[0]
    assert lines[1].startswith("ingest: 80 events sent (27 frames) in 20 s; last 10 s: 4.0 events/s, 1.30 frames/s; sensor time 5.3 s"), lines[1]
    assert (progress.events, progress.frames) == (90, 30)


def test_no_progress_lines_with_interval_zero(caplog):
    progress = ProgressLog(0.0, clock=iter(range(100)).__next__)
    with caplog.at_level(logging.INFO, logger="locnerf_services.sensor_ingest.service"):
        for index in range(50):
            progress.sent(OdometryEvent(index / 15.0, torch.eye(4, dtype=torch.float64)))
    assert not caplog.records and progress.events == 50
