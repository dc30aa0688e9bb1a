"""Gaps of real odometry: nothing is sent for them, and the prediction across one carries the noise of its time."""

from __future__ import annotations

import torch

from locnerf.config import preset
from locnerf.filter.estimate import carry_estimate
from locnerf.filter.localizer import Localizer
from locnerf.geometry import make_pose, pose_inverse, se3_exp
from locnerf.messages.codec import encode
from locnerf.messages.schemas import InitialPoseCommand
from locnerf.odometry.tracks import OdometryTrack
from locnerf.sim.events import GroundTruthEvent, OdometryEvent
from locnerf.sim.paths import WorldPath
from locnerf.sim.scenario import ScenarioConfig, build_scenario, run_stamps
from locnerf.sim.sensors import CameraConfig
from locnerf.sim.stream import simulated_events
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld
from tests.services.filter_harness import Harness, odometry_payload


def _started(config) -> Localizer:
    localizer = Localizer(config, torch.Generator().manual_seed(7), dtype=torch.float64)
    localizer.initialize_gaussian(torch.eye(4, dtype=torch.float64), torch.eye(6, dtype=torch.float64) * 1e-6)
    return localizer


def test_prediction_across_four_periods_draws_twice_the_noise():
    """σ·√periods: the same draws as a filter whose configured noise is doubled (the oracle)."""
    config = preset("llff")
    motion = config.motion
    doubled = config.model_copy(
        update={
            "motion": motion.model_copy(
                update={"rotation_sigma": tuple(2 * s for s in motion.rotation_sigma), "translation_sigma": tuple(2 * s for s in motion.translation_sigma)}
            )
        }
    )
    step = se3_exp(torch.tensor([0.01, 0.0, 0.02, 0.1, 0.0, -0.05], dtype=torch.float64))
    widened, reference = _started(config), _started(doubled)
    widened.predict(step, periods=4.0)
    reference.predict(step)
    assert torch.allclose(widened.particles.poses, reference.particles.poses, atol=1e-12)
    assert torch.allclose(widened.noise_sigma(0.5), widened.noise_sigma(1.0))  # never less than one period's noise


def test_filter_loop_widens_the_carried_covariance_over_a_gap_and_counts_it():
    world = ProceduralWorld.default()
    harness = Harness(world)
    loop = harness.loop
    start = world.sample_camera_pose(torch.Generator().manual_seed(3))
    covariance = torch.diag(torch.tensor([0.02, 0.02, 0.02, 0.05, 0.05, 0.05], dtype=torch.float64) ** 2)
    loop.handle_initial_pose(encode(InitialPoseCommand(stamp=0.0, T_world_cam=start.tolist(), covariance=covariance.tolist())))
    step = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.0, 0.0, -0.02], dtype=torch.float64))
    anchor = loop.localizer.estimate()
    harness.collect(loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
    harness.collect(loop.handle_odometry(odometry_payload(4 / 15, step)))  # frames 1-3 were gaps: 4 periods
    sigma = loop.localizer.noise_sigma()
    expected = carry_estimate(carry_estimate(anchor, None, sigma), world.normalization.increment_to_map(step), 2 * sigma)
    published = torch.tensor(harness.poses[-1].covariance, dtype=torch.float64)
    assert torch.allclose(published, world.normalization.covariance_to_metric(expected.covariance), atol=1e-12)
    assert loop.counters()["odometry_gaps"] == 1


def test_a_track_with_gaps_sends_no_odometry_for_them_and_its_poses_for_the_rest():
    world = ProceduralWorld.default()
    path = WorldPath(world, FigureEightTrajectory(), CameraConfig())
    config = ScenarioConfig(duration=1.0, image_rate=5.0)
    stamps = run_stamps(path, config)
    poses = torch.stack([se3_exp(torch.tensor([0.0, 0.1 * k, 0.0, 0.05 * k, 0.0, 0.0], dtype=torch.float64)) for k in range(len(stamps))])
    valid = torch.ones(len(stamps), dtype=torch.bool)
    valid[[3, 4, 9]] = False
    track = OdometryTrack(poses, valid, "file:test.txt")
    events = list(simulated_events(path, config, track=track))
    odometry = [e for e in events if isinstance(e, OdometryEvent)]
    assert [e.stamp for e in odometry] == stamps[valid].tolist()
    assert len([e for e in events if isinstance(e, GroundTruthEvent)]) == len(stamps)
    body = poses[valid] @ pose_inverse(path.T_body_cam)
    assert torch.allclose(torch.stack([e.T_odom_body for e in odometry]), body)
    scenario = build_scenario(path, config, world.normalization, track=track)
    assert scenario.odometry_label == "file:test.txt" and torch.equal(scenario.odometry_valid, valid)
