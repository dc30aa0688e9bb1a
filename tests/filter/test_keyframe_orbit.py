"""Orbit draws around keyframes: fresh particles that circle what a keyframe looks at, level."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.filter.recovery import KeyframeCandidates, RecoveryConfig, keyframe_draws, keyframe_orbit_particles, keyframe_particles
from locnerf.geometry import make_pose, so3_exp

_UP = (0.0, 0.0, 1.0)
_DEPTH = 4.0


def _looking_at_origin(position: list[float]) -> torch.Tensor:
    """A level camera (x axis horizontal, up = z) at ``position`` whose optical axis (−z) passes through the origin."""
    eye = torch.tensor(position, dtype=torch.float64)
    back = eye / eye.norm()  # the camera's z axis points away from what it looks at
    right = torch.linalg.cross(torch.tensor(_UP, dtype=torch.float64), back)
    right = right / right.norm()
    return make_pose(torch.stack([right, torch.linalg.cross(back, right), back], dim=1), eye)


def _candidates() -> KeyframeCandidates:
    """Two level keyframes 4 units from the origin, one looking horizontally, one from 30° above."""
    elevation = math.radians(30.0)
    return KeyframeCandidates(
        torch.stack([_looking_at_origin([_DEPTH, 0.0, 0.0]), _looking_at_origin([0.0, _DEPTH * math.cos(elevation), _DEPTH * math.sin(elevation)])]),
        spacing=0.5,
    )


def test_without_turn_or_distance_noise_every_draw_looks_at_the_circled_point_from_the_same_distance_and_level(generator):
    """Oracle: the pivot point p = K (0, 0, −d) is the origin for both keyframes; every draw's optical
    axis passes through it at distance d, and its x axis stays horizontal (a level camera stays level)."""
    poses = keyframe_orbit_particles(_candidates(), 2000, _DEPTH, 0.4, 0.0, 0.0, _UP, generator)
    positions = poses[:, :3, 3]
    torch.testing.assert_close(positions.norm(dim=1), torch.full((2000,), _DEPTH, dtype=torch.float64), rtol=0, atol=1e-9)
    looking = -poses[:, :3, 2]
    torch.testing.assert_close(looking, -positions / _DEPTH, rtol=0, atol=1e-9)
    torch.testing.assert_close(poses[:, 2, 0], torch.zeros(2000, dtype=torch.float64), rtol=0, atol=1e-9)  # x axis ⟂ up
    assert float((positions - _candidates().poses[torch.arange(2000) % 2, :3, 3]).norm(dim=1).max()) > 0.5  # they did move


def test_arc_spread_matches_the_angles_drawn(generator):
    """The horizontally looking keyframe: azimuth and elevation are both angles seen from the origin,
    so the angle between keyframe and draw has E[θ²] ≈ 2 (σ/d)² (small angles; 4000 draws, standard
    error of a mean square ~2 %; tolerance 8 %); the draws alternate over the candidates."""
    candidates = _candidates()
    arc = 0.2
    poses = keyframe_orbit_particles(candidates, 4000, _DEPTH, arc, 0.0, 0.0, _UP, generator)
    keyframe = candidates.poses[0, :3, 3]
    drawn = poses[0::2, :3, 3]
    cosine = (drawn @ keyframe) / (drawn.norm(dim=1) * keyframe.norm())
    angles = torch.arccos(cosine.clamp(-1.0, 1.0))
    assert float((angles**2).mean()) == pytest.approx(2 * (arc / _DEPTH) ** 2, rel=0.08)
    second = poses[1::2, :3, 3]
    assert float((second - candidates.poses[1, :3, 3]).norm(dim=1).median()) < 4 * arc  # around the second keyframe


def test_distance_and_turn_noise_have_the_stated_spread(generator):
    """Distance σ 0.05 (the offset along the viewing axis) and a turn of 1° per axis: the distance to
    the origin scatters by σ and the optical axis misses the origin by about d · 1° (tolerance 8 %)."""
    poses = keyframe_orbit_particles(_candidates(), 4000, _DEPTH, 0.3, 0.05, math.radians(1.0), _UP, generator)
    positions = poses[:, :3, 3]
    assert float(positions.norm(dim=1).std()) == pytest.approx(0.05, rel=0.08)
    looking = -poses[:, :3, 2]
    miss = torch.linalg.cross(looking, -positions).norm(dim=1)  # distance of the origin from the optical axis
    # the axis turns by two independent per-axis angles (x and y): E[miss²] = 2 (d σ)²
    assert float((miss**2).mean()) == pytest.approx(2 * (_DEPTH * math.radians(1.0)) ** 2, rel=0.08)


def test_keyframe_draws_are_gaussian_without_an_orbit_depth_and_orbit_draws_with_one():
    candidates = _candidates()
    config = RecoveryConfig(keyframe_position_sigma=0.5, keyframe_rotation_sigma_deg=5.0)
    drawn = keyframe_draws(candidates, 50, config, _UP, torch.Generator().manual_seed(3))
    assert torch.equal(drawn, keyframe_particles(candidates, 50, 0.25, math.radians(5.0), torch.Generator().manual_seed(3)))
    orbit = config.model_copy(update={"keyframe_orbit_depth": _DEPTH, "keyframe_orbit_distance_sigma": 0.01})
    drawn = keyframe_draws(candidates, 50, orbit, _UP, torch.Generator().manual_seed(3))
    expected = keyframe_orbit_particles(candidates, 50, _DEPTH, 0.25, 0.01, math.radians(5.0), _UP, torch.Generator().manual_seed(3))
    assert torch.equal(drawn, expected)


@pytest.mark.parametrize(("depth", "up", "message"), [(0.0, _UP, "orbit depth=0.0"), (-1.0, _UP, "orbit depth=-1.0"), (_DEPTH, (0.0, 0.0, 0.0), "up=")])
def test_bad_orbit_arguments_are_refused_with_the_value(generator, depth, up, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        keyframe_orbit_particles(_candidates(), 10, depth, 0.1, 0.0, 0.0, up, generator)


def test_a_turned_keyframe_keeps_its_roll_relative_to_gravity(generator):
    """A keyframe rolled by 10° about its viewing axis: orbit draws keep the 10° (azimuth about up and
    elevation about the camera's x axis do not change the angle between x and the horizontal)."""
    level = _looking_at_origin([_DEPTH, 0.0, 0.0])
    rolled = level.clone()
    rolled[:3, :3] = level[:3, :3] @ so3_exp(torch.tensor([0.0, 0.0, math.radians(10.0)], dtype=torch.float64))
    poses = keyframe_orbit_particles(KeyframeCandidates(rolled[None], spacing=0.5), 500, _DEPTH, 0.4, 0.0, 0.0, _UP, generator)
    roll = torch.rad2deg(torch.asin(poses[:, 2, 0].abs()))  # elevation of the x axis above the horizontal
    torch.testing.assert_close(roll, torch.full((500,), 10.0, dtype=torch.float64), rtol=0, atol=1e-6)
