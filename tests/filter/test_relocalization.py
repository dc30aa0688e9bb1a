"""Relocalization after a detected kidnapping: refining updates around the posterior, the recovery count,
and keyframe draws whose spread is given in map units."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.annealing import AnnealingStage
from locnerf.filter.estimate import ParticleEstimate
from locnerf.filter.keyframes import index_from_views
from locnerf.filter.recovery import InjectionPlan, KeyframeCandidates, RecoveryConfig, RecoveryMonitor, injection_poses, keyframe_draws, refining_draws
from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.geometry import make_pose, relative_pose, se3_log, so3_exp
from locnerf.maps.keyframes import joined_index
from locnerf.render.camera import PinholeIntrinsics


def detected_monitor(relocalize_updates: int, verify_updates: int = 0) -> RecoveryMonitor:
    """A monitor that has seen ten normal updates (log-likelihood 20) and then a 14-nat drop (detected)."""
    config = RecoveryConfig(enabled=True, alpha_fast=1.0, tolerance=6.0, max_fraction=0.9, relocalize_updates=relocalize_updates, verify_updates=verify_updates)
    monitor = RecoveryMonitor(config)
    for _ in range(10):
        assert monitor.observe(20.0).fraction == 0.0
    plan = monitor.observe(6.0)
    assert plan.fraction == pytest.approx(0.9) and not plan.around_estimate
    return monitor


def test_a_detection_is_followed_by_refining_updates_then_a_fresh_level():
    monitor = detected_monitor(relocalize_updates=3)
    refining = [monitor.observe(value) for value in (-40.0, 5.0, 30.0)]  # not tested: whatever the likelihood
    assert all(p.around_estimate and p.fraction == pytest.approx(0.3) for p in refining)
    assert monitor.log_slow is None and monitor.log_fast is None  # the new place's level is learned afresh
    assert monitor.observe(2.0).fraction == 0.0  # 18 nats below the old level: not a second kidnapping
    assert monitor.observe(2.0).fraction == 0.0
    assert monitor.fired == 1
    assert monitor.observe(-20.0).fraction > 0.0  # a drop from the new level is
    assert monitor.fired == 2


def test_without_refining_updates_the_monitor_tests_every_update():
    monitor = detected_monitor(relocalize_updates=0)
    assert monitor.observe(6.0).fraction == pytest.approx(0.9)  # still low: injects again (one streak, one recovery)
    assert monitor.fired == 1


def test_a_change_of_likelihood_kind_keeps_the_refining_updates():
    monitor = detected_monitor(relocalize_updates=2)
    monitor.forget_level()
    assert monitor.observe(0.0).around_estimate
    monitor.reset()  # a re-initialisation ends it
    assert not monitor.observe(0.0).around_estimate


def test_a_new_place_under_the_tracked_level_is_relocalized_again():
    monitor = detected_monitor(relocalize_updates=2, verify_updates=3)
    assert all(monitor.observe(30.0).around_estimate for _ in range(2))
    assert [monitor.observe(value).fraction for value in (-40.0, 2.0)] == [0.0, 0.0]  # settling: not tested
    # level log(mean(e^-40, e^2, e^2)) = 2 - log(1.5) = 1.59, 18.4 nats under the tracked 20 (> 6): a wrong place
    assert monitor.observe(2.0).fraction == pytest.approx(0.9)
    assert monitor.fired == 2
    assert monitor.observe(2.0).around_estimate  # refining again around the second relocalization


def test_a_new_place_at_the_tracked_level_is_kept_and_seeds_the_averages():
    monitor = detected_monitor(relocalize_updates=1, verify_updates=3)
    assert monitor.observe(-40.0).around_estimate
    assert [monitor.observe(value).fraction for value in (16.0, 15.0, 15.5)] == [0.0, 0.0, 0.0]  # 4-5 nats under 20: kept
    assert monitor.log_slow == pytest.approx(math.log((math.exp(16.0) + math.exp(15.0) + math.exp(15.5)) / 3))
    assert monitor.observe(14.0).fraction == 0.0  # the new level's own tolerance: 2.1 nats under it
    assert monitor.observe(5.0).fraction == pytest.approx(0.9)  # 10.5 nats under it: tested again, a second detection
    assert monitor.fired == 2


def test_the_verification_compares_levels_of_one_likelihood_kind():
    config = RecoveryConfig(enabled=True, alpha_fast=1.0, tolerance=6.0, max_fraction=0.9, relocalize_updates=1, verify_updates=2)
    levels = {"rendered": -10.0, "warped": 20.0}
    for kind, expected in (("rendered", 0.0), ("warped", 0.9)):
        monitor = RecoveryMonitor(config)
        for name in ("rendered", "warped"):
            for _ in range(5):
                assert monitor.observe(levels[name], kind=name).fraction == 0.0
        assert monitor.observe(5.0, kind="warped").fraction == pytest.approx(0.9)  # 15 nats under the warped level
        assert monitor.observe(0.0, kind="warped").around_estimate
        monitor.observe(-12.0, kind=kind)
        assert monitor.observe(-12.0, kind=kind).fraction == pytest.approx(expected)  # 2 under the rendered level, 32 under the warped


def test_a_change_of_kind_restarts_the_verification():
    monitor = detected_monitor(relocalize_updates=1, verify_updates=2)
    monitor.observe(0.0)
    assert monitor.observe(-30.0).fraction == 0.0
    assert monitor.observe(20.0, kind="warped").fraction == 0.0  # a new kind: the window starts again, nothing tracked for it
    assert monitor.observe(-30.0, kind="warped").fraction == 0.0  # no level of this kind before the detection: kept
    assert monitor.fired == 1


def estimate_with(covariance: torch.Tensor) -> ParticleEstimate:
    pose = make_pose(so3_exp(torch.tensor([0.1, 0.7, -0.2], dtype=torch.float64)), torch.tensor([1.0, -0.5, 2.0], dtype=torch.float64))
    return ParticleEstimate(pose=pose, covariance=covariance, spread=0.1, effective_sample_size=100.0, particle_count=100, stage=AnnealingStage.COARSE)


def test_refining_draws_follow_the_scaled_posterior_covariance_with_floors():
    """The tangent vectors of 40000 draws about the estimate have the covariance refine_scale² Σ + floor²
    (float64 oracle: the sample covariance, within 4 % on the diagonal and 0.03 in correlation)."""
    root = torch.tensor(
        [[0.05, 0, 0, 0, 0, 0], [0.01, 0.03, 0, 0, 0, 0], [0, 0, 0.0, 0, 0, 0], [0, 0.02, 0, 0.1, 0, 0], [0, 0, 0, 0.05, 0.2, 0], [0, 0, 0, 0, 0, 0.0]]
    )
    covariance = (root @ root.T).double()
    config = RecoveryConfig(refine_scale=0.5, refine_min_position=0.01, refine_min_rotation_deg=1.0)
    estimate = estimate_with(covariance)
    draws = refining_draws(estimate, 40000, config, torch.Generator().manual_seed(4))
    tangents = se3_log(relative_pose(estimate.pose.expand_as(draws), draws))
    expected = 0.25 * covariance + torch.diag(torch.tensor([math.radians(1.0)] * 3 + [0.01] * 3, dtype=torch.float64) ** 2)
    sample = torch.cov(tangents.T)
    torch.testing.assert_close(sample.diagonal(), expected.diagonal(), rtol=0.04, atol=0)
    scale = expected.diagonal().sqrt()
    torch.testing.assert_close(sample / torch.outer(scale, scale), expected / torch.outer(scale, scale), rtol=0, atol=0.03)


def test_refining_draws_add_the_pivot_swings_covariance():
    """With refine_pivot_*, 40000 draws about a tight estimate have the covariance floor² + Π, Π the swings' (a turn θ
    about the camera's y axis with a shift of depth·θ along x, about x with −depth·θ along y): float64 oracle, the
    sample covariance within 4 % on the diagonal and 0.03 in correlation, and the turn and shift correlated (+1 for y/x)."""
    config = RecoveryConfig(refine_min_position=0.001, refine_min_rotation_deg=0.05, refine_pivot_depth=1.5, refine_pivot_sigma_deg=1.0)
    estimate = estimate_with(torch.zeros(6, 6, dtype=torch.float64))
    draws = refining_draws(estimate, 40000, config, torch.Generator().manual_seed(5))
    tangents = se3_log(relative_pose(estimate.pose.expand_as(draws), draws))
    swing = math.radians(1.0)
    expected = torch.diag(torch.tensor([math.radians(0.05)] * 3 + [0.001] * 3, dtype=torch.float64) ** 2)
    expected[0, 0] += swing**2
    expected[1, 1] += swing**2
    expected[3, 3] += (1.5 * swing) ** 2
    expected[4, 4] += (1.5 * swing) ** 2
    expected[1, 3] = expected[3, 1] = 1.5 * swing**2
    expected[0, 4] = expected[4, 0] = -1.5 * swing**2
    sample = torch.cov(tangents.T)
    torch.testing.assert_close(sample.diagonal(), expected.diagonal(), rtol=0.04, atol=0)
    scale = expected.diagonal().sqrt()
    correlation = sample / torch.outer(scale, scale)
    torch.testing.assert_close(correlation, expected / torch.outer(scale, scale), rtol=0, atol=0.03)
    assert correlation[1, 3] > 0.95 and correlation[0, 4] < -0.95


def test_a_refining_plan_needs_the_covariance():
    plan = InjectionPlan(fraction=0.3, local_radius=0.1, local_yaw=0.0, around_estimate=True)
    bounds = torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64)
    estimate = estimate_with(torch.eye(6, dtype=torch.float64) * 1e-4)
    with pytest.raises(ValueError, match="pass the ParticleEstimate"):
        injection_poses(plan, 10, RecoveryConfig(), estimate.pose, bounds, (0.0, 1.0, 0.0), torch.Generator().manual_seed(0))
    poses = injection_poses(plan, 10, RecoveryConfig(), estimate, bounds, (0.0, 1.0, 0.0), torch.Generator().manual_seed(0))
    assert poses.shape == (10, 4, 4)


def test_keyframe_position_spread_in_map_units_replaces_the_spacing_multiple():
    """Keyframes 6 mm apart (spacing 0.006): with keyframe_position_sigma_map = 0.1 the draws spread 0.1 per
    axis (sample std of 20000 draws within 3 %), not 0.5 x 0.006."""
    candidates = KeyframeCandidates(torch.eye(4, dtype=torch.float64)[None], spacing=0.006)
    config = RecoveryConfig(keyframe_position_sigma=0.5, keyframe_position_sigma_map=0.1, keyframe_rotation_sigma_deg=0.0)
    draws = keyframe_draws(candidates, 20000, config, (0.0, 1.0, 0.0), torch.Generator().manual_seed(2))
    torch.testing.assert_close(draws[:, :3, 3].std(dim=0), torch.full((3,), 0.1, dtype=torch.float64), rtol=0.03, atol=0)
    spacing = keyframe_draws(
        candidates, 20000, config.model_copy(update={"keyframe_position_sigma_map": None}), (0.0, 1.0, 0.0), torch.Generator().manual_seed(2)
    )
    torch.testing.assert_close(spacing[:, :3, 3].std(dim=0), torch.full((3,), 0.003, dtype=torch.float64), rtol=0.03, atol=0)


def test_a_joined_index_finds_views_of_either_part():
    """A lattice-like index and a reference index joined: each part's own views are found first, with their poses."""
    camera = PinholeIntrinsics(fx=16.0, fy=16.0, cx=7.5, cy=5.5, width=16, height=12)
    views = torch.rand(6, 12, 16, 3, generator=torch.Generator().manual_seed(1))
    poses = make_pose(torch.eye(3, dtype=torch.float64).expand(6, 3, 3), torch.arange(18, dtype=torch.float64).reshape(6, 3))
    first, second = index_from_views(poses[:4], views[:4], camera, 16), index_from_views(poses[4:], views[4:], camera, 16)
    joined = joined_index(first, second)
    assert len(joined) == 6 and joined.spacing == first.spacing
    for view in range(6):
        found, _ = joined.query(views[view], 1)
        torch.testing.assert_close(found[0], poses[view])
    with pytest.raises(ValueError, match="expected the same"):
        joined_index(first, index_from_views(poses[4:], views[4:, :6, :8], camera.scaled(0.5), 8))


def test_a_log_average_is_not_lifted_by_one_sharp_update():
    """The likelihoods' average jumps to within log(1/α_slow) of one sharp update (e^30 among e^20s) and the
    next ordinary update reads as a 7-nat drop; the logs' average moves by α·10 = 0.5 and reads nothing."""
    for average, fired in (("likelihood", 1), ("log", 0)):
        monitor = RecoveryMonitor(RecoveryConfig(enabled=True, average=average, alpha_slow=0.05, alpha_fast=1.0, tolerance=6.0, max_fraction=0.9))
        for value in [20.0] * 10 + [30.0, 20.0]:
            monitor.observe(value)
        expected = math.log(0.95 * math.exp(20.0) + 0.05 * math.exp(30.0)) if average == "likelihood" else 20.5
        assert monitor.fired == fired
        assert monitor.log_slow == pytest.approx(
            0.95 * expected + 0.05 * 20.0 if average == "log" else math.log(0.95 * math.exp(expected) + 0.05 * math.exp(20.0))
        )


def test_searches_are_due_on_the_updates_after_the_refining_ones():
    search = CrossEntropyConfig(start_position=0.05)
    monitor = RecoveryMonitor(RecoveryConfig(enabled=True, relocalize_updates=2, search=search, search_updates=2))
    monitor.refine(2)
    assert monitor.take_search() is None
    monitor.observe(0.0)
    assert monitor.take_search() is None  # still refining
    monitor.observe(0.0)  # the last refining update
    assert [monitor.take_search() for _ in range(3)] == [search, search, None]
    monitor.refine(1)
    monitor.observe(0.0)
    monitor.reset()  # a re-initialisation forgets them
    assert monitor.take_search() is None
    without = RecoveryMonitor(RecoveryConfig(enabled=True))
    without.refine(1)
    without.observe(0.0)
    assert without.take_search() is None
