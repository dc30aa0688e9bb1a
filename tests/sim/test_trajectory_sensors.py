"""Trajectories, the VIO and camera simulators, and the simulated event stream."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.field.protocol import MapNormalization
from locnerf.geometry import pose_inverse, rotation_error_deg, se3_log
from locnerf.geometry.validation import InvalidPoseError
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent
from locnerf.sim.paths import WorldPath
from locnerf.sim.scenario import ScenarioConfig, build_scenario
from locnerf.sim.sensors import CameraConfig, VioConfig, observe_image, simulate_odometry
from locnerf.sim.stream import simulated_events
from locnerf.sim.trajectory import FigureEightTrajectory, TrajectoryConfig
from locnerf.sim.world import ProceduralWorld

QUIET = dict(rotation_noise=0.0, translation_noise=0.0)


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


@pytest.fixture(scope="module")
def trajectory() -> FigureEightTrajectory:
    return FigureEightTrajectory()


def test_default_trajectory_is_a_free_closed_loop_at_walking_speed(world, trajectory):
    trajectory.check_free(world.is_free, clearance=0.3)
    times = torch.linspace(0.0, trajectory.duration, 2001, dtype=torch.float64)
    _, velocity = trajectory.positions_and_velocities(times)
    speed = velocity.norm(dim=-1)
    assert 0.3 <= speed.min() and speed.max() <= 0.8
    assert torch.allclose(trajectory.pose_at(0.0), trajectory.pose_at(trajectory.duration), atol=1e-9)
    poses = trajectory.poses_at(times)
    depth, _ = world.cast(poses[:, :3, 3].contiguous(), -poses[:, :3, 2].contiguous())
    assert depth.min() >= 1.0  # always something to see, not a wall in the face


def test_velocity_is_the_derivative_of_position_and_the_camera_looks_ahead(trajectory):
    times = torch.linspace(0.3, 20.0, 50, dtype=torch.float64)
    h = 1e-5
    position, velocity = trajectory.positions_and_velocities(times)
    numeric = (trajectory.positions_and_velocities(times + h)[0] - trajectory.positions_and_velocities(times - h)[0]) / (2 * h)
    assert torch.allclose(numeric, velocity, atol=1e-7)
    # The optical axis (-z) stays within the head-motion amplitude (8° yaw, 5° pitch) of the motion direction.
    axis = -trajectory.poses_at(times)[:, :3, 2]
    flat = velocity * torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64)
    cosine = (axis * flat).sum(-1) / flat.norm(dim=-1)
    assert cosine.min() > math.cos(math.radians(10.0))


def test_trajectory_refuses_nan_times_and_a_path_through_a_box(world):
    with pytest.raises(ValueError, match="finite"):
        FigureEightTrajectory().poses_at(torch.tensor([0.0, float("nan")]))
    through_pillars = FigureEightTrajectory(TrajectoryConfig(centre=(0.0, 1.7, 0.0), amplitude_x=3.0, orientation=0.0))
    with pytest.raises(ValueError, match="free space"):
        through_pillars.check_free(world.is_free)


def test_odometry_without_noise_or_drift_reproduces_the_truth(trajectory):
    truth = trajectory.poses_at(torch.arange(0.0, 10.0, 1 / 15, dtype=torch.float64))
    odometry = simulate_odometry(truth, VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, **QUIET), torch.Generator().manual_seed(0))
    assert torch.allclose(odometry, truth, atol=1e-9)


def test_scale_drift_is_exactly_the_configured_fraction_of_the_displacement(trajectory):
    truth = trajectory.poses_at(torch.arange(0.0, 10.0, 1 / 15, dtype=torch.float64))
    odometry = simulate_odometry(truth, VioConfig(translation_drift=0.01, yaw_drift_rate=0.0, **QUIET), torch.Generator().manual_seed(0))
    displacement = truth[:, :3, 3] - truth[0, :3, 3]
    assert torch.allclose(odometry[:, :3, 3] - truth[:, :3, 3], 0.01 * displacement, atol=1e-9)


def test_yaw_drift_grows_at_the_configured_rate_when_the_body_stays_level():
    level = FigureEightTrajectory(TrajectoryConfig(head_pitch=0.0))
    stamps = torch.arange(0.0, 12.0, 1 / 15, dtype=torch.float64)
    rate = math.radians(1.0)
    odometry = simulate_odometry(level.poses_at(stamps), VioConfig(translation_drift=0.0, yaw_drift_rate=rate, **QUIET), torch.Generator())
    error = rotation_error_deg(odometry, level.poses_at(stamps))
    # Level body: every increment's yaw error adds about the same world axis, so the error is exactly ω t.
    assert torch.allclose(error, torch.rad2deg(rate * stamps), atol=1e-6)


def test_increment_noise_has_the_configured_standard_deviation(trajectory):
    """Tolerance: 2,000 increments × 3 axes give the sample std within 5 % (its own std is ~1.3 %)."""
    truth = trajectory.poses_at(torch.arange(2001, dtype=torch.float64) / 15)
    config = VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, rotation_noise=2e-3, translation_noise=5e-3)
    odometry = simulate_odometry(truth, config, torch.Generator().manual_seed(3))
    true_increments = pose_inverse(truth[:-1]) @ truth[1:]
    noisy_increments = pose_inverse(odometry[:-1]) @ odometry[1:]
    xi = se3_log(pose_inverse(true_increments) @ noisy_increments)
    assert xi[:, :3].std() == pytest.approx(2e-3, rel=0.05)
    assert xi[:, 3:].std() == pytest.approx(5e-3, rel=0.05)
    assert xi.mean(dim=0).abs().max() < 4 * 5e-3 / math.sqrt(2000)


def test_odometry_is_reproducible_from_the_seed_and_refuses_bad_poses(trajectory):
    truth = trajectory.poses_at(torch.arange(0.0, 2.0, 1 / 15, dtype=torch.float64))
    a = simulate_odometry(truth, VioConfig(), torch.Generator().manual_seed(4))
    b = simulate_odometry(truth, VioConfig(), torch.Generator().manual_seed(4))
    assert torch.equal(a, b)
    bad = truth.clone()
    bad[3, 0, 0] = float("nan")
    with pytest.raises(InvalidPoseError, match="NaN"):
        simulate_odometry(bad, VioConfig(), torch.Generator())
    with pytest.raises(InvalidPoseError, match=r"\(\.\.\., 4, 4\)"):
        simulate_odometry(torch.zeros(5, 3, 4), VioConfig(), torch.Generator())


def test_camera_noise_and_gain_follow_the_configuration(world, trajectory):
    pose = trajectory.pose_at(1.0)
    clean = world.render_image(pose).float()
    quarter_period = 5.0  # sin(2π · 5 / 20) = 1: the gain is at its peak 1 + a
    config = CameraConfig(pixel_noise=0.0, gain_amplitude=0.2)
    brighter = observe_image(world.render_image, pose, quarter_period, world.default_intrinsics, config, torch.Generator())
    assert torch.allclose(brighter, (1.2 * clean).clamp(0, 1), atol=1e-6)
    noisy = observe_image(world.render_image, pose, 0.0, world.default_intrinsics, CameraConfig(pixel_noise=0.02), torch.Generator().manual_seed(1))
    inside = (clean > 0.1) & (clean < 0.9)  # away from the clamp
    # Tolerance: 57,600 channels give the sample std within 2 %.
    assert (noisy - clean)[inside].std() == pytest.approx(0.02, rel=0.02)


SHORT_RUN = ScenarioConfig(seed=2, duration=2.0, image_rate=5.0)


def payload(event: GroundTruthEvent | OdometryEvent | ImageEvent) -> torch.Tensor:
    """What an event carries: the image's pixels, the odometry pose or the true pose."""
    if isinstance(event, ImageEvent):
        return torch.from_numpy(event.pixels)
    return event.T_odom_body if isinstance(event, OdometryEvent) else event.T_world_cam


@pytest.fixture(scope="module")
def short_run(world, trajectory) -> list:
    return list(simulated_events(WorldPath(world, trajectory, CameraConfig()), SHORT_RUN))


def test_stream_is_time_ordered_at_the_configured_rates(short_run):
    stamps = [event.stamp for event in short_run]
    assert stamps == sorted(stamps)
    odometry = [e for e in short_run if isinstance(e, OdometryEvent)]
    images = [e for e in short_run if isinstance(e, ImageEvent)]
    # 0..2 s inclusive at 15 Hz and 5 Hz (images lie on the odometry grid: a rate that divides 15 Hz keeps them exact)
    assert len(odometry) == 31 and len(images) == 11
    assert [e.stamp for e in images] == pytest.approx([k / 5 for k in range(11)])
    # At a shared stamp the odometry comes first, so a filter has predicted before it corrects.
    first_image = next(i for i, e in enumerate(short_run) if isinstance(e, ImageEvent))
    assert isinstance(short_run[first_image - 1], OdometryEvent) and short_run[first_image - 1].stamp == 0.0


def test_stream_images_are_the_world_seen_from_the_true_pose_and_reproducible(world, trajectory, short_run):
    image = next(e for e in short_run if isinstance(e, ImageEvent) and e.stamp == 1.0)
    truth = next(e for e in short_run if isinstance(e, GroundTruthEvent) and e.stamp == 1.0)
    torch.testing.assert_close(truth.T_world_cam, trajectory.pose_at(1.0), atol=1e-12, rtol=0)
    clean = world.render_image(truth.T_world_cam).float()
    assert (torch.from_numpy(image.pixels).float() / 255 - clean).abs().mean() < 0.02
    again = list(simulated_events(WorldPath(world, trajectory, CameraConfig()), SHORT_RUN))
    assert len(again) == len(short_run) and all(type(a) is type(b) and torch.equal(payload(a), payload(b)) for a, b in zip(short_run, again))


def test_stream_applies_the_camera_extrinsic_and_refuses_a_bad_one(world, trajectory):
    mount = [[1.0, 0, 0, 0.1], [0, 1.0, 0, 0.0], [0, 0, 1.0, 0.0], [0, 0, 0, 1.0]]
    path = WorldPath(world, trajectory, CameraConfig(T_body_cam=mount))
    perfect = VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, **QUIET)
    scenario = build_scenario(path, ScenarioConfig(duration=0.5, vio=perfect), MapNormalization())
    # The truth is the camera's pose, the odometry the body's (the trajectory's).
    assert torch.allclose(scenario.truth[0], trajectory.pose_at(0.0) @ torch.tensor(mount, dtype=torch.float64))
    torch.testing.assert_close(scenario.odometry, trajectory.poses_at(scenario.stamps), atol=1e-9, rtol=0)
    with pytest.raises(InvalidPoseError, match="T_body_cam"):
        WorldPath(world, trajectory, CameraConfig(T_body_cam=[[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
