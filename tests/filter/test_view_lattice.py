"""The view-lattice start: lattice poses, the lattice index, and re-drawn particles keeping the known tilt."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from locnerf.filter.initialization import rotation_about_axis
from locnerf.filter.keyframe_start import KeyframeStartConfig, ViewLatticeConfig, seed_around_keyframes, seed_start, with_tilt_of
from locnerf.filter.recovery import KeyframeCandidates, RecoveryConfig
from locnerf.geometry import make_pose, so3_exp
from locnerf.maps.view_lattice import build_lattice_index, lattice_poses
from locnerf.sim.world import ProceduralWorld

UP = (0.1, -0.9, -0.42)  # tilted like the kitchen map's up axis


def _unit(vector: tuple[float, float, float]) -> torch.Tensor:
    axis = torch.tensor(vector, dtype=torch.float64)
    return axis / axis.norm()


def _horizontal_view(rotations: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """(N, 3) unit horizontal part of the viewing directions (the oracle for headings)."""
    forward = -rotations[:, :, 2]
    return F.normalize(forward - (forward @ up)[:, None] * up, dim=1)


def test_redrawn_poses_keep_the_replaced_tilt_and_take_the_drawn_heading_and_position(generator):
    up = _unit(UP)
    count = 50
    drawn = make_pose(so3_exp(torch.randn(count, 3, dtype=torch.float64, generator=generator)), torch.randn(count, 3, dtype=torch.float64, generator=generator))
    tilted = make_pose(so3_exp(torch.randn(count, 3, dtype=torch.float64, generator=generator)), torch.zeros(count, 3, dtype=torch.float64))
    result = with_tilt_of(drawn, tilted, UP)
    rotations = result[:, :3, :3]
    torch.testing.assert_close(rotations.transpose(1, 2) @ rotations, torch.eye(3, dtype=torch.float64).expand(count, 3, 3), atol=1e-12, rtol=0)
    torch.testing.assert_close(result[:, :3, 3], drawn[:, :3, 3], atol=0, rtol=0)
    # Gravity seen in the camera frame is the tilted pose's; the horizontal viewing direction the drawn one's.
    torch.testing.assert_close(rotations.transpose(1, 2) @ up, tilted[:, :3, :3].transpose(1, 2) @ up, atol=1e-12, rtol=0)
    torch.testing.assert_close(_horizontal_view(rotations, up), _horizontal_view(drawn[:, :3, :3], up), atol=1e-9, rtol=0)


def test_seed_start_without_keep_tilt_is_the_plain_keyframe_start_and_with_it_keeps_the_tilt():
    up = _unit(UP)
    candidates = KeyframeCandidates(
        make_pose(so3_exp(torch.tensor([[0.3, 0.2, 0.1], [-0.2, 1.0, 0.0]], dtype=torch.float64)), torch.zeros(2, 3, dtype=torch.float64)), 0.2
    )
    tilt = rotation_about_axis(torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), torch.tensor([-0.4], dtype=torch.float64))[0]
    start = make_pose(rotation_about_axis(up, torch.linspace(0, 6, 40, dtype=torch.float64)) @ tilt, torch.full((40, 3), 9.0, dtype=torch.float64))
    recovery = RecoveryConfig(keyframe_rotation_sigma_deg=10.0)
    plain = seed_around_keyframes(start, candidates, 0.5, recovery, torch.Generator().manual_seed(3), UP)
    same = seed_start(start, candidates, KeyframeStartConfig(share=0.5), recovery, torch.Generator().manual_seed(3), UP)
    assert torch.equal(plain, same)
    kept = seed_start(start, candidates, KeyframeStartConfig(share=0.5, keep_tilt=True), recovery, torch.Generator().manual_seed(3), UP)
    moved = (kept != start).flatten(1).any(dim=1)
    assert int(moved.sum()) == 20
    torch.testing.assert_close(kept[moved][:, :3, 3], plain[moved][:, :3, 3], atol=0, rtol=0)
    gravity = kept[:, :3, :3].transpose(1, 2) @ up
    torch.testing.assert_close(gravity, (tilt.T @ up).expand(40, 3), atol=1e-12, rtol=0)


def test_lattice_poses_cover_the_widened_bounds_at_every_heading_and_pitch():
    config = ViewLatticeConfig(step=0.5, margin=0.25, yaw_step_deg=90.0, pitches_deg=(-20.0, 10.0))
    bounds = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]], dtype=torch.float64)
    poses = lattice_poses(bounds, UP, config)
    positions = poses[:, :3, 3]
    assert poses.shape == (4 * 3 * 2 * 4 * 2, 4, 4)  # x: -0.25..1.25 (4), y: -0.25..0.75 (3), z: -0.25..0.25 (2)
    assert float(positions.min()) == pytest.approx(-0.25) and float(positions[:, 0].max()) == pytest.approx(1.25)
    up = _unit(UP)
    rotations = poses[:, :3, :3]
    pitch = torch.rad2deg(torch.asin((-rotations[:, :, 2]) @ up))
    assert sorted({round(float(p), 6) for p in pitch}) == [-20.0, 10.0]
    torch.testing.assert_close(rotations[:, :, 0] @ up, torch.zeros(len(poses), dtype=torch.float64), atol=1e-12, rtol=0)  # no roll
    views = _horizontal_view(rotations[:8], up)  # the first position's 4 headings × 2 pitches
    angles = torch.rad2deg(torch.acos((views[::2] @ views[0]).clamp(-1, 1)))
    torch.testing.assert_close(angles, torch.tensor([0.0, 90.0, 180.0, 90.0], dtype=torch.float64), atol=1e-6, rtol=0)


def test_an_image_seen_from_a_lattice_view_finds_a_view_at_its_place_first():
    world = ProceduralWorld.default()
    config = ViewLatticeConfig(step=1.0, margin=0.0, yaw_step_deg=45.0, pitches_deg=(0.0,), width=12, supersample=1)
    index = build_lattice_index(world, world.default_intrinsics, config)
    poses = lattice_poses(world.camera_bounds(), world.normalization.up, config)
    assert len(index) == len(poses) and index.spacing == 1.0
    for which in (5, len(poses) // 2):
        nudge = make_pose(so3_exp(torch.tensor([0.0, math.radians(3.0), 0.0], dtype=torch.float64)), torch.tensor([0.05, 0.0, 0.0], dtype=torch.float64))
        found, _ = index.query(world.render_image(poses[which] @ nudge), 1)
        assert torch.equal(found[0], poses[which])
