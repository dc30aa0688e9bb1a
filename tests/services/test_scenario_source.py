"""The ingest's scenario source serves exactly the offline tracking scenario."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.map_lens import MapLens
from locnerf.geometry import make_pose, pose_inverse, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf.sim.paths import WorldPath, read_sequence_frames
from locnerf.sim.scenario import ScenarioConfig, build_scenario
from locnerf.sim.sensors import CameraConfig, VioConfig
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from locnerf_services.sensor_ingest.scenario_source import ScenarioSourceConfig

VIO = VioConfig(translation_drift=0.02, translation_noise=3e-3)


def test_world_scenario_events_match_the_offline_scenario():
    config = IngestConfig(source="scenario", seed=3, scenario=ScenarioSourceConfig(duration=1.0, image_rate=5.0, vio=VIO, kidnap_at=0.5))
    events = list(sensor_events(config))
    world = ProceduralWorld.default()
    offline = build_scenario(
        WorldPath(world, FigureEightTrajectory(), CameraConfig()),
        ScenarioConfig(duration=1.0, image_rate=5.0, vio=VIO, kidnap_at=0.5, seed=3),
        world.normalization,
    )
    odometry = [e for e in events if isinstance(e, OdometryEvent)]
    truth = [e for e in events if isinstance(e, GroundTruthEvent)]
    images = [e for e in events if isinstance(e, ImageEvent)]
    assert [e.stamp for e in odometry] == offline.stamps.tolist() == [e.stamp for e in truth]
    assert torch.allclose(torch.stack([e.T_odom_body for e in odometry]), offline.odometry)
    assert torch.allclose(torch.stack([e.T_world_cam for e in truth]), offline.truth)
    assert [e.stamp for e in images] == [float(offline.stamps[t]) for t in offline.image_ticks]
    assert len(images) == 6  # 0, 0.2, ..., 1.0 s
    first = offline.image(offline.image_ticks[0], torch.Generator().manual_seed(4))  # the offline run's image seed: seed + 1
    assert torch.allclose(torch.from_numpy(images[0].pixels).float() / 255, first.float().clamp(0, 1), atol=1 / 255)
    stamps = [e.stamp for e in events]
    assert stamps == sorted(stamps)


def test_lego_orbit_is_served_with_synthesised_odometry(shared_data):
    """A NeRF-synthetic sequence through the generic reader. Its frames lie 0.22 units apart: at a
    nominal 1 unit/s they are 3 odometry periods (0.2 s) apart, so 5 Hz images are every frame."""
    scenario = ScenarioSourceConfig(sequence=str(shared_data / "nerf_synthetic" / "lego_test_orbit"), downscale=8, duration=2.0, image_rate=5.0, speed=1.0)
    events = list(sensor_events(IngestConfig(source="scenario", scenario=scenario)))
    images = [e for e in events if isinstance(e, ImageEvent)]
    odometry = [e for e in events if isinstance(e, OdometryEvent)]
    assert len(odometry) == 31  # 15 Hz over 2 s, both ends
    assert images and images[0].pixels.shape == (50, 50, 3) and images[0].pixels.dtype.name == "uint8"
    assert [e.stamp for e in images] == [odometry[3 * k].stamp for k in range(11)]  # 0, 0.2, ..., 2.0 s
    moved = torch.linalg.vector_norm(odometry[-1].T_odom_body[:3, 3] - odometry[0].T_odom_body[:3, 3])
    assert float(moved) > 1.0  # about 1 unit per second along the orbit


def test_an_rgbd_sequence_is_served_with_its_depth_images_in_millimetres(shared_data):
    """7-Scenes test frames at the camera's 30 Hz, 5 Hz images: each image carries the depth file of its
    frame, subsampled as the reader does, as the uint16 millimetres of the file (no reading stays 0)."""
    kitchen = shared_data / "7scenes_redkitchen"
    scenario = ScenarioSourceConfig(sequence=str(kitchen), split="test", downscale=8, frame_rate=30.0, duration=0.4, image_rate=5.0)
    images = [e for e in sensor_events(IngestConfig(source="scenario", scenario=scenario)) if isinstance(e, ImageEvent)]
    assert [round(e.stamp, 6) for e in images] == [0.0, 0.2, 0.4]  # the test split's frames 0, 6 and 12: seq-02's 600, 606, 612
    for image, frame in zip(images, (600, 606, 612)):
        raw = cv2.imread(str(kitchen / "seq-02" / f"frame-{frame:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        stride = raw.shape[1] // image.depth.millimetres.shape[1]
        expected = raw[::stride, ::stride].copy()
        expected[expected == 65535] = 0
        assert image.depth is not None and image.depth.millimetres.dtype == np.uint16 and image.pixels.shape == (60, 80, 3)
        assert image.depth.intrinsics.width == image.depth.millimetres.shape[1] == 80
        assert np.array_equal(image.depth.millimetres, expected)


def test_a_sequence_on_its_maps_colour_camera_sends_the_depth_cameras_offset(shared_data):
    """With the map's T_depth_colour the served truth is the colour camera's (the depth camera's pose times it)
    and every depth frame carries the depth camera's pose in the colour camera's frame, in metres."""
    kitchen = shared_data / "7scenes_redkitchen"
    offset = make_pose(so3_exp(torch.tensor([-0.014, 0.002, 0.003], dtype=torch.float64)), torch.tensor([0.027, 0.015, 0.005], dtype=torch.float64))
    settings = {"sequence": str(kitchen), "split": "test", "downscale": 8, "frame_rate": 30.0, "duration": 0.2, "image_rate": 5.0}
    plain = list(sensor_events(IngestConfig(source="scenario", scenario=ScenarioSourceConfig(**settings))))
    moved = list(sensor_events(IngestConfig(source="scenario", scenario=ScenarioSourceConfig(**settings, T_depth_colour=offset.tolist()))))
    truths = [(a.T_world_cam, b.T_world_cam) for a, b in zip(plain, moved) if isinstance(a, GroundTruthEvent)]
    assert truths
    for depth_pose, colour_pose in truths:
        torch.testing.assert_close(colour_pose, depth_pose @ offset)
    images = [e for e in moved if isinstance(e, ImageEvent)]
    assert images and all(e.depth.T_cam_depth is not None for e in images)
    torch.testing.assert_close(images[0].depth.T_cam_depth, pose_inverse(offset))
    with pytest.raises(ValueError, match="T_depth_colour: expected a rigid transform"):
        ScenarioSourceConfig(**settings, T_depth_colour=(2.0 * offset).tolist())


KITCHEN_SFM_LENS = MapLens(
    lens=PinholeIntrinsics(fx=522.3, fy=522.3, cx=319.5, cy=239.5, width=640, height=480),
    distortion=(-0.03, 0.0, 0.0, 0.0),
    camera=PinholeIntrinsics(fx=130.6, fy=130.6, cx=79.5, cy=59.5, width=160, height=120),
)
"""A lens like the one ``map build --sfm`` estimates for the kitchen, and a 160×120 map camera."""


def test_a_sequence_for_an_sfm_built_map_is_served_through_the_maps_lens(shared_data):
    """With the lens an SfM map records, the served images are the offline queries': each resampled through the lens
    onto the map's camera (``MapLens.apply``, the resampling ``read_on_map_camera`` gives single image and global), and
    they carry the map's camera; the record crosses the service configuration as plain data."""
    kitchen = shared_data / "7scenes_redkitchen"
    lens = KITCHEN_SFM_LENS
    settings = {"sequence": str(kitchen), "split": "test", "downscale": 8, "frame_rate": 30.0, "duration": 0.2, "image_rate": 5.0}
    scenario = ScenarioSourceConfig.model_validate({**settings, "lens": lens.model_dump()})
    images = [e for e in sensor_events(IngestConfig(source="scenario", scenario=scenario)) if isinstance(e, ImageEvent)]
    plain = [e for e in sensor_events(IngestConfig(source="scenario", scenario=ScenarioSourceConfig(**settings))) if isinstance(e, ImageEvent)]
    assert images and images[0].intrinsics == lens.camera.scaled(80 / 160)
    frames = read_sequence_frames(kitchen, "test", 8)
    expected = lens.apply(frames.subset([0])).images[0]
    served = torch.from_numpy(images[0].pixels).float() / 255.0
    assert float((served - expected).abs().max()) <= 0.5 / 255 + 1e-6  # the 8-bit rounding of what is sent
    assert not np.array_equal(images[0].pixels, plain[0].pixels)
