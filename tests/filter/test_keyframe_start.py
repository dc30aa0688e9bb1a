"""The keyframe-seeded global start: which particles are re-drawn, where, and only once per uniform start."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.keyframe_start import KeyframeStartConfig, seed_around_keyframes
from locnerf.filter.localizer import Localizer
from locnerf.filter.localizer_config import LocalizerConfig, SearchRegion
from locnerf.filter.recovery import KeyframeCandidates, RecoveryConfig, RecoveryMonitor
from locnerf.geometry import make_pose, rotation_error_deg, se3_log, so3_exp, translation_error
from locnerf.maps.keyframes import build_keyframe_index
from locnerf.sim.world import ProceduralWorld


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


def _far_poses(count: int) -> torch.Tensor:
    """Identity-rotation poses at x = 100 … (count-1)+100: far from every candidate below."""
    positions = torch.zeros(count, 3, dtype=torch.float64)
    positions[:, 0] = 100.0 + torch.arange(count, dtype=torch.float64)
    return make_pose(torch.eye(3, dtype=torch.float64).expand(count, 3, 3), positions)


def test_the_share_of_particles_is_redrawn_around_the_candidates_and_the_rest_kept(generator):
    candidates = KeyframeCandidates(
        torch.stack(
            [make_pose(so3_exp(torch.tensor([0.0, 0.7 * k, 0.0], dtype=torch.float64)), torch.full((3,), float(k), dtype=torch.float64)) for k in range(3)]
        ),
        spacing=0.2,
    )
    recovery = RecoveryConfig(keyframe_position_sigma=0.5, keyframe_rotation_sigma_deg=5.0)
    before = _far_poses(200)
    after = seed_around_keyframes(before, candidates, 0.75, recovery, generator)
    moved = (after != before).flatten(1).any(dim=1)
    assert int(moved.sum()) == 150
    assert torch.equal(after[~moved], before[~moved])
    # Every re-drawn pose lies within 5 σ (0.1 units per axis, 5° per axis) of its nearest candidate.
    offsets = torch.stack([se3_log(torch.linalg.inv(candidate) @ after[moved]) for candidate in candidates.poses])  # (3, 150, 6)
    nearest = offsets[..., 3:].norm(dim=-1).argmin(dim=0)
    closest = offsets[nearest, torch.arange(150)]
    assert float(closest[:, 3:].abs().max()) < 5 * 0.5 * 0.2
    assert float(closest[:, :3].abs().max()) < 5 * math.radians(5.0)
    assert sorted(torch.bincount(nearest, minlength=3).tolist()) == [50, 50, 50]  # spread equally


def test_no_share_changes_nothing_and_a_bad_share_is_refused(generator):
    candidates = KeyframeCandidates(torch.eye(4, dtype=torch.float64)[None], spacing=1.0)
    poses = _far_poses(10)
    assert torch.equal(seed_around_keyframes(poses, candidates, 0.0, RecoveryConfig(), generator), poses)
    with pytest.raises(ValueError, match="share=1.5"):
        seed_around_keyframes(poses, candidates, 1.5, RecoveryConfig(), generator)


def _localizer(world: ProceduralWorld, generator: torch.Generator, share: float, keyframe_poses: torch.Tensor | None) -> Localizer:
    keyframes = None if keyframe_poses is None else build_keyframe_index(world.render_rays, keyframe_poses, world.default_intrinsics)
    low, high = world.camera_bounds().double().tolist()
    region = SearchRegion(low=tuple(low), high=tuple(high), up=world.normalization.up)
    recovery = RecoveryConfig(keyframe_position_sigma=0.05)  # σ: 5 % of the keyframes' spacing
    config = LocalizerConfig(particles=400, keyframe_start=KeyframeStartConfig(share=share), recovery=recovery)
    return Localizer(config, generator, dtype=torch.float64, region=region, keyframes=keyframes)


def test_the_first_image_after_a_global_start_seeds_particles_near_the_truth_once(world, generator):
    """40 keyframes; the image is seen from 3 cm and 0.6° off keyframe 17. Uniform particles over the
    room come no closer than 0.1 units and 10° together; after the keyframe start, particles that
    close are found (σ around a keyframe: 5 % of the keyframes' spacing, 5° per axis)."""
    poses = torch.stack([world.sample_camera_pose(generator) for _ in range(40)])
    truth = poses[17] @ make_pose(so3_exp(torch.tensor([0.0, 0.01, 0.0], dtype=torch.float64)), torch.tensor([0.02, 0.0, -0.02], dtype=torch.float64))
    image = world.render_image(truth)
    localizer = _localizer(world, generator, 0.8, poses)
    localizer.initialize_uniform(localizer.region)

    def near_truth() -> int:
        particles = localizer.particles.poses
        close = (translation_error(particles, truth.expand_as(particles)) < 0.1) & (rotation_error_deg(particles, truth.expand_as(particles)) < 10.0)
        return int(close.sum())

    assert near_truth() == 0
    assert localizer.seed_from_image(image, world.default_intrinsics) == 320
    assert near_truth() >= 3
    seeded = localizer.particles.poses.clone()
    assert localizer.seed_from_image(image, world.default_intrinsics) == 0  # once per start
    assert torch.equal(localizer.particles.poses, seeded)
    localizer.initialize_uniform(localizer.region)  # a new global start seeds again
    assert localizer.seed_from_image(image, world.default_intrinsics) == 320
    localizer.initialize_global(poses[3], half_width=0.5, up=world.normalization.up)  # so does the paper's global protocol
    assert near_truth() == 0
    assert localizer.seed_from_image(image, world.default_intrinsics) == 320
    assert near_truth() >= 3
    localizer.initialize_inerf(poses[3])  # a start near a known pose is left as it is
    assert localizer.seed_from_image(image, world.default_intrinsics) == 0


def test_only_a_global_start_with_keyframes_and_a_share_is_seeded(world, generator):
    poses = torch.stack([world.sample_camera_pose(generator) for _ in range(8)])
    image = world.render_image(poses[0])
    camera = world.default_intrinsics
    without_keyframes = _localizer(world, generator, 0.8, None)
    without_keyframes.initialize_uniform(without_keyframes.region)
    no_share = _localizer(world, generator, 0.0, poses)
    no_share.initialize_uniform(no_share.region)
    explicit = _localizer(world, generator, 0.8, poses)
    explicit.initialize(poses[:1].expand(400, 4, 4).clone())
    for localizer in (without_keyframes, no_share, explicit):
        before = localizer.particles.poses.clone()
        assert localizer.seed_from_image(image, camera) == 0
        assert torch.equal(localizer.particles.poses, before)
    assert not LocalizerConfig().uses_keyframes()
    assert LocalizerConfig(keyframe_start=KeyframeStartConfig(share=0.5)).uses_keyframes()
    assert LocalizerConfig(recovery=RecoveryConfig(enabled=True, keyframe_share=0.5)).uses_keyframes()


@pytest.mark.parametrize("refine_updates", [0, 2])
def test_a_seeded_start_refines_for_refine_updates_without_counting_a_recovery(world, generator, refine_updates):
    """With recovery enabled and ``refine_updates`` = 2 the two updates after the seeding re-draw
    ``refine_fraction`` of the resampled particles from the cloud's Gaussian (recovery's refining
    draws), not counted as recoveries; the third is tested as usual (equal likelihoods: no drop)."""
    poses = torch.stack([world.sample_camera_pose(generator) for _ in range(8)])
    keyframes = build_keyframe_index(world.render_rays, poses, world.default_intrinsics)
    low, high = world.camera_bounds().double().tolist()
    region = SearchRegion(low=tuple(low), high=tuple(high), up=world.normalization.up)
    start = KeyframeStartConfig(share=0.8, refine_updates=refine_updates)
    config = LocalizerConfig(particles=200, keyframe_start=start, recovery=RecoveryConfig(enabled=True, refine_fraction=0.25))
    localizer = Localizer(config, generator, dtype=torch.float64, region=region, keyframes=keyframes)
    localizer.initialize_uniform(region)
    assert localizer.seed_from_image(world.render_image(poses[0]), world.default_intrinsics) == 160
    injected = []
    for _ in range(3):
        snap = localizer.snapshot()
        injected.append(localizer.merge(snap.epoch, snap.generation, snap.ids, torch.zeros(len(snap.ids), dtype=torch.float64)).injected)
    assert injected == ([50, 50, 0] if refine_updates else [0, 0, 0])  # KLD off: 200 particles, a quarter re-drawn
    assert localizer.counters["recoveries"] == 0


def test_a_negative_refining_count_is_refused():
    with pytest.raises(ValueError, match="refining updates=-1"):
        RecoveryMonitor(RecoveryConfig()).refine(-1)
    with pytest.raises(ValueError, match="refine_updates"):
        KeyframeStartConfig(refine_updates=-1)
