"""Convergence protection along the valley: a few particles swung about the pivot point before each update."""

from __future__ import annotations

import pytest
import torch

from locnerf.filter import Localizer, LocalizerConfig
from locnerf.filter.localizer import ConvergenceProtectionConfig
from locnerf.filter.motion import MotionNoiseConfig
from locnerf.geometry import make_pose, se3_exp

_DEPTH = 4.0


def _localizer(generator: torch.Generator, count: int, half_width: float) -> Localizer:
    config = LocalizerConfig(
        particles=200,
        motion=MotionNoiseConfig(pivot_depth=_DEPTH),
        convergence_protection=ConvergenceProtectionConfig(count=count, half_width=half_width, pivot=True),
    )
    return Localizer(config, generator, dtype=torch.float64)


def test_swung_particles_keep_looking_at_their_pivot_point_from_the_same_distance(generator):
    """Oracle: the point ``pivot_depth`` ahead of each re-drawn particle is where it was, the particle
    stays at that distance from it, moved sideways by at most half_width (plus the sagitta); the others are untouched."""
    localizer = _localizer(generator, count=30, half_width=0.3)
    start = make_pose(torch.eye(3, dtype=torch.float64).expand(200, 3, 3), torch.zeros(200, 3, dtype=torch.float64))
    start = start @ se3_exp(torch.randn(200, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.1)
    localizer.initialize(start.clone())
    snap = localizer.snapshot()
    moved = (snap.poses - start).abs().amax(dim=(1, 2)) > 1e-12
    assert int(moved.sum()) == 30
    ahead = torch.tensor([0.0, 0.0, -_DEPTH, 1.0], dtype=torch.float64)
    torch.testing.assert_close((snap.poses @ ahead)[moved], (start @ ahead)[moved], rtol=0, atol=1e-9)
    steps = (snap.poses[moved, :3, 3] - start[moved, :3, 3]).norm(dim=1)
    assert float(steps.max()) <= 0.3 * 2**0.5 * 1.01
    assert float(steps.max()) > 0.1  # they did swing
    torch.testing.assert_close(snap.poses[~moved], start[~moved], rtol=0, atol=0)


def test_pivot_protection_needs_a_pivot_depth():
    with pytest.raises(ValueError, match="motion.pivot_depth > 0"):
        LocalizerConfig(convergence_protection=ConvergenceProtectionConfig(pivot=True))
