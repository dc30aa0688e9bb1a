"""Poses are held for their ground truth, which can reach a subscriber after them (another route)."""

from __future__ import annotations

import pytest

from locnerf.messages.schemas import PoseEstimate, PoseStamped
from locnerf_cli.monitor import GroundTruthMatcher, ScoredPoses

IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def estimate(stamp: float, x: float = 0.0) -> PoseEstimate:
    pose = [row[:] for row in IDENTITY]
    pose[0][3] = x
    zero = [[0.0] * 6 for _ in range(6)]
    return PoseEstimate(stamp=stamp, T_world_cam=pose, covariance=zero, particle_count=1, spread=0.0, effective_sample_size=1.0, mode="coarse", epoch=0)


def truth(stamp: float) -> PoseStamped:
    return PoseStamped(stamp=stamp, T_world_cam=IDENTITY)


def test_a_pose_waits_for_its_truth_and_is_scored_when_it_arrives():
    matcher = GroundTruthMatcher()
    poses = ScoredPoses(matcher, wait_s=0.5)
    matcher.add_truth(truth(1.0))
    poses.add(estimate(1.0, x=0.1), 10.0)
    poses.add(estimate(1.1, x=0.2), 10.0)  # its truth is still on its way
    poses.add(estimate(1.2, x=0.3), 10.0)
    released = poses.release(10.1)
    assert [(e.stamp, round(err.translation, 6)) for e, err in released] == [(1.0, 0.1)]
    matcher.add_truth(truth(1.1))
    released = poses.release(10.2)
    assert [(e.stamp, round(err.translation, 6)) for e, err in released] == [(1.1, 0.2)]
    matcher.add_truth(truth(1.3))  # a later truth: 1.2's will not come
    assert [(e.stamp, err) for e, err in poses.release(10.3)] == [(1.2, None)]


def test_without_ground_truth_poses_go_at_once_and_a_missing_truth_is_waited_for_at_most_wait_s():
    matcher = GroundTruthMatcher()
    poses = ScoredPoses(matcher, wait_s=0.5)
    poses.add(estimate(1.0), 10.0)
    assert [(e.stamp, err) for e, err in poses.release(10.0)] == [(1.0, None)]
    matcher.add_truth(truth(1.0))
    poses.add(estimate(2.0), 10.0)
    assert poses.release(10.4) == []
    released = poses.release(10.5)
    assert [(e.stamp, err) for e, err in released] == [(2.0, None)]


@pytest.mark.parametrize("stamp", [0.5, 1.0])
def test_settled_once_its_truth_or_a_later_one_arrived(stamp):
    matcher = GroundTruthMatcher()
    matcher.add_truth(truth(1.0))
    assert matcher.settled(estimate(stamp)) and not matcher.settled(estimate(1.5))
