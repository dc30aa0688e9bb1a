"""Stand-ins for particles drawn after an update's snapshot: the nearest measured neighbour's log-likelihood
inside the measured cloud (a float64 loop as the oracle), the median outside it."""

from __future__ import annotations

import torch

from locnerf.filter.ancestor_scores import borrowed_log_likelihoods
from locnerf.filter.convergence_protection import ConvergenceProtectionConfig
from locnerf.geometry import make_pose, se3_exp
from locnerf.geometry.averaging import chordal_rotation_mean
from locnerf.geometry.so3 import so3_log
from tests.filter.test_localizer import make_localizer

SCALES = torch.tensor([0.05, 0.02, 0.08, 0.1, 0.3, 0.2], dtype=torch.float64)  # rotation (rad), translation: unequal axes


def gaussian_cloud(generator: torch.Generator, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(count, 4, 4) poses Exp(ξ), ξ ~ N(0, diag(SCALES²)), and a sharp log-likelihood of each, −‖ξ / SCALES‖² · 4."""
    xi = torch.randn(count, 6, generator=generator, dtype=torch.float64) * SCALES
    return se3_exp(xi), -4.0 * ((xi / SCALES) ** 2).sum(dim=1)


def oracle(per_particle: torch.Tensor, unscored: torch.Tensor, poses: torch.Tensor, reach: float) -> torch.Tensor:
    """One particle at a time, in float64: tangent residuals about the measured particles' chordal mean rotation and
    mean residual, Mahalanobis distances under the inverse of their sample covariance, the nearest measured one's value."""
    scored = [j for j in range(len(poses)) if not unscored[j]]
    rotation = chordal_rotation_mean(poses[scored, :3, :3])

    def raw(pose: torch.Tensor) -> torch.Tensor:
        return torch.cat((so3_log(rotation.T @ pose[:3, :3]), rotation.T @ pose[:3, 3]))

    centre = sum(raw(poses[j]) for j in scored) / len(scored)
    inverse = torch.linalg.inv(sum(torch.outer(raw(poses[j]) - centre, raw(poses[j]) - centre) for j in scored) / (len(scored) - 1))

    residuals = [raw(pose) - centre for pose in poses]
    result = per_particle.clone()
    for i in range(len(poses)):
        if not unscored[i] or float(residuals[i] @ inverse @ residuals[i]) > reach**2:
            continue
        distances = [float((residuals[i] - residuals[j]) @ inverse @ (residuals[i] - residuals[j])) for j in scored]
        result[i] = per_particle[scored[min(range(len(scored)), key=distances.__getitem__)]]
    return result


def test_drawn_particles_inside_the_cloud_take_their_nearest_measured_neighbours_value(generator):
    poses, truth = gaussian_cloud(generator, 300)
    unscored = torch.zeros(300, dtype=torch.bool)
    unscored[:90] = True
    per_particle = truth.clone()
    per_particle[unscored] = truth[~unscored].median()
    borrowed = borrowed_log_likelihoods(per_particle, unscored, poses, reach=4.1)
    expected = oracle(per_particle, unscored, poses, reach=4.1)
    assert torch.allclose(borrowed, expected, rtol=0, atol=1e-12)
    assert torch.equal(borrowed[~unscored], truth[~unscored])
    # Most of a Gaussian lies inside 4.1 (99 % in six dimensions), and a neighbour's value is nearer the truth than the median.
    inside = borrowed[:90] != per_particle[:90]
    assert int(inside.sum()) >= 80
    assert (borrowed[:90] - truth[:90]).abs().mean() < (per_particle[:90] - truth[:90]).abs().mean()


def test_a_particle_outside_the_measured_cloud_and_a_reach_of_zero_keep_the_median(generator):
    poses, truth = gaussian_cloud(generator, 100)
    far = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64))  # 10 σ along x
    poses = torch.cat((poses, far[None]))
    unscored = torch.zeros(101, dtype=torch.bool)
    unscored[[0, 100]] = True
    per_particle = torch.cat((truth, truth[:1]))
    per_particle[unscored] = -7.0
    borrowed = borrowed_log_likelihoods(per_particle, unscored, poses, reach=4.1)
    assert borrowed[100] == -7.0 and borrowed[0] != -7.0
    assert torch.equal(borrowed_log_likelihoods(per_particle, unscored, poses, reach=0.0), per_particle)


def grid_of_particles() -> torch.Tensor:
    """27 particles (identity rotation) on the 3 × 3 × 3 grid {0, 1, 2}³, float64; index 13 is the centre (1, 1, 1)."""
    axis = torch.arange(3, dtype=torch.float64)
    positions = torch.cartesian_prod(axis, axis, axis)
    return make_pose(torch.eye(3, dtype=torch.float64).expand(27, 3, 3), positions)


def test_a_result_from_before_a_redraw_lets_a_redrawn_particle_next_to_the_favoured_one_survive(generator):
    """Two snapshots in flight; the second re-draws one particle next to the grid's centre, the only pose the first
    result finds plausible. Merged, the first result keeps the re-drawn particle (its neighbour's value); with a
    reach of zero it gives it the median and the resampling kills it."""
    survivors = []
    for reach in (4.1, 0.0):
        seeded = torch.Generator().manual_seed(int(generator.initial_seed()))
        localizer = make_localizer(seeded, particles=27, resampler="systematic", borrow_reach=reach)
        localizer.initialize(grid_of_particles())
        first = localizer.snapshot()
        localizer.config = localizer.config.model_copy(update={"convergence_protection": ConvergenceProtectionConfig(count=1, half_width=0.3)})
        second = localizer.snapshot()
        redrawn = int(torch.nonzero((first.poses != second.poses).any(dim=-1).any(dim=-1)).squeeze())
        assert redrawn != 13  # the centre itself stays
        scores = torch.full((27,), -1e6, dtype=torch.float64)
        scores[13] = 0.0
        localizer.merge(first.epoch, first.generation, first.ids, scores)
        positions = localizer.particles.positions
        survivors.append(bool(((positions - second.poses[redrawn, :3, 3]).abs().sum(dim=1) < 1e-12).any()))
        assert bool(((positions - torch.ones(3, dtype=torch.float64)).abs().sum(dim=1) < 1e-12).any())
    assert survivors == [True, False]
