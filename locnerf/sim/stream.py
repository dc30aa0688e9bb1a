"""A simulated run as a time-ordered stream of sensor events, the way the ingest service publishes it.

Every odometry stamp yields its ground truth, then its odometry, then (on image stamps) the image
(with its depth image when the path has a depth camera: an RGB-D sequence),
so a filter has predicted to an image's stamp before it corrects with it. Poses are metric (the
wire carries metric poses); images are rendered lazily, segment by segment
(:func:`locnerf.sim.scenario.scenario_segments`), and quantised to 8-bit RGB. The data are those
of :func:`locnerf.sim.scenario.build_scenario` for the same path and configuration, and the
images draw their noise from ``seed + 1``, as the offline ``locnerf eval tracking`` does.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np
import torch

from locnerf.field.protocol import MapNormalization
from locnerf.odometry.tracks import OdometryTrack
from locnerf.sim.events import DepthFrame, GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent, depth_millimetres, rgb8
from locnerf.sim.paths import CameraPath
from locnerf.sim.scenario import ScenarioConfig, TrackingScenario, scenario_segments


def scenario_events(segments: Iterable[TrackingScenario], image_generator: torch.Generator, distinct_frames: int = 0) -> Iterator[SensorEvent]:
    """Ground truth and odometry at every stamp of the segments, then the image on image stamps.

    Args:
        segments: consecutive pieces of one run, truth in the metric world frame.
        image_generator: draws of the image noise.
        distinct_frames: render only the first N images and send them again in turn (0: render
            every image). An overload test uses it to send images faster than the renderer
            could; the images then no longer match the poses.
    """
    if distinct_frames < 0:
        raise ValueError(f"distinct_frames {distinct_frames}: expected >= 0 (0 renders every image)")
    rendered: list[tuple[np.ndarray, DepthFrame | None]] = []
    images_sent = 0
    for segment in segments:
        image_ticks = set(segment.image_ticks)
        valid = segment.odometry_valid.tolist() if segment.odometry_valid is not None else None
        for tick, stamp in enumerate(segment.stamps.tolist()):
            yield GroundTruthEvent(stamp, segment.truth[tick])
            if valid is None or valid[tick]:  # a gap of real odometry sends nothing
                yield OdometryEvent(stamp, segment.odometry[tick])
            if tick not in image_ticks:
                continue
            if distinct_frames and len(rendered) == distinct_frames:
                pixels, depth = rendered[images_sent % distinct_frames]
            else:
                pixels, depth = rgb8(segment.image(tick, image_generator)), _depth_frame(segment, tick)
                if distinct_frames:
                    rendered.append((pixels, depth))
            images_sent += 1
            yield ImageEvent(stamp, pixels, segment.path.intrinsics, depth)


def _depth_frame(segment: TrackingScenario, tick: int) -> DepthFrame | None:
    """The depth image taken with the image at ``tick`` (metres on the path) as sent, or None without a depth camera."""
    depth = segment.depth(tick)
    return None if depth is None else DepthFrame(depth_millimetres(depth.depth), depth.intrinsics, depth.T_cam_depth)


def simulated_events(path: CameraPath, config: ScenarioConfig, distinct_frames: int = 0, track: OdometryTrack | None = None) -> Iterator[SensorEvent]:
    """The sensor events of the run along ``path`` (see :func:`scenario_events`), poses in the metric world frame;
    with ``track``, its real odometry (and gaps) instead of the simulated one."""
    segments = scenario_segments(path, config, MapNormalization(), track=track)
    return scenario_events(segments, torch.Generator().manual_seed(config.seed + 1), distinct_frames)
