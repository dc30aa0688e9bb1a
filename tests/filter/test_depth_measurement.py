"""Depth measurement (RGB-D): float64 and per-particle oracles, truncation, the true pose in the procedural world, the localizer."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.config import preset
from locnerf.data.seven_scenes import depth_points
from locnerf.field.surface_distance import SurfaceDistance, SurfaceDistanceConfig
from locnerf.filter.depth_measurement import (
    DepthConfig,
    DepthObservation,
    depth_log_likelihoods,
    render_depth_image,
    rendered_depth_log_likelihoods,
    sample_depth_pixels,
    surface_distance_log_likelihoods,
    warped_depth_log_likelihoods,
)
from locnerf.filter.localizer import Localizer
from locnerf.filter.measurement_config import WarpConfig
from locnerf.filter.warp import render_reference
from locnerf.geometry import make_pose, pose_inverse, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.world import ProceduralWorld
from tests.filter.world_poses import poses_around, true_pose

COLOUR = PinholeIntrinsics.from_fov(64, 48, math.radians(70))
DEPTH = PinholeIntrinsics.from_fov(40, 30, math.radians(60))
FINE_DEPTH = PinholeIntrinsics.from_fov(100, 75, math.radians(65))  # narrower than the colour camera, pixels not commensurate with it


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


def _depth_image(world: ProceduralWorld, pose: torch.Tensor, camera: PinholeIntrinsics = DEPTH) -> DepthObservation:
    """The exact depth image seen from ``pose`` (4, 4) (float64 rays): depth along the optical axis, 0 where a ray meets nothing."""
    return render_depth_image(world.render_surface, pose.double(), camera)


def _naive_depth_log_likelihood(predicted: list[float], observed: list[float], config: DepthConfig) -> float:
    """One particle, one residual at a time, in float64."""
    total = 0.0
    for d, o in zip(predicted, observed):
        residual = d - o
        total += min(residual * residual, config.truncation**2) if math.isfinite(residual) else config.truncation**2
    return config.exponent * (math.log(len(predicted)) - math.log(max(total, 1e-12)))


def test_vectorised_likelihood_matches_a_float64_loop(generator: torch.Generator) -> None:
    """Missing predictions (NaN, inf) and residuals beyond the truncation count c²; float32 input agrees with float64."""
    config = DepthConfig(truncation=0.2, exponent=3.0)
    predicted = 1.0 + 2.0 * torch.rand(7, 50, generator=generator, dtype=torch.float64)
    observed = predicted[0] + 0.3 * torch.randn(50, generator=generator, dtype=torch.float64)
    predicted[2, :4] = torch.nan
    predicted[3, 5] = torch.inf
    poses = torch.eye(4, dtype=torch.float64).expand(7, 4, 4)
    fast = depth_log_likelihoods(poses, predicted, observed, config)
    slow = torch.tensor([_naive_depth_log_likelihood(p.tolist(), observed.tolist(), config) for p in predicted], dtype=torch.float64)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(depth_log_likelihoods(poses.float(), predicted.float(), observed.float(), config), slow, rtol=1e-5, atol=1e-5)
    assert torch.isfinite(depth_log_likelihoods(poses[:1], observed[None], observed, config)).all()  # a perfect fit: large, finite


def test_a_residual_counts_at_most_the_truncation() -> None:
    """An outlier of 0.1 m, 1 m or 100 m weighs the same: c² = truncation²."""
    config = DepthConfig(truncation=0.1)
    observed = torch.full((10,), 2.0, dtype=torch.float64)
    predicted = observed.expand(4, 10).clone()
    predicted[:, 0] += torch.tensor([0.1, 1.0, 100.0, -50.0], dtype=torch.float64)
    predicted[:, 1] += 0.01
    scores = depth_log_likelihoods(torch.eye(4, dtype=torch.float64).expand(4, 4, 4), predicted, observed, config)
    torch.testing.assert_close(scores, scores[:1].expand(4), rtol=0, atol=1e-12)
    expected = config.exponent * (math.log(10) - math.log(0.1**2 + 0.01**2))
    assert abs(float(scores[0]) - expected) < 1e-9


def test_depth_pixels_are_valid_readings(generator: torch.Generator) -> None:
    """Distinct valid pixels when there are enough, repeats only when there are fewer, an error when there are none."""
    depth = torch.zeros(DEPTH.height, DEPTH.width)
    depth[5:15, 10:30] = 2.0  # 200 valid
    depth[0, 0] = 9.0  # beyond max_depth
    observation = DepthObservation(depth, DEPTH)
    pixels = sample_depth_pixels(observation, DepthConfig(pixels=150), generator)
    assert pixels.shape == (150, 2) and pixels.dtype == torch.float32
    assert bool((depth[pixels[:, 1].long(), pixels[:, 0].long()] == 2.0).all())
    assert len({tuple(p) for p in pixels.tolist()}) == 150
    many = sample_depth_pixels(observation, DepthConfig(pixels=500), generator)
    assert len(many) == 500 and bool((depth[many[:, 1].long(), many[:, 0].long()] == 2.0).all())
    with pytest.raises(ValueError, match="no reading within"):
        sample_depth_pixels(DepthObservation(torch.zeros(DEPTH.height, DEPTH.width), DEPTH), DepthConfig(), generator)


def test_bad_observation_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match=r"DepthObservation.depth of shape \(30, 40, 1\): expected \(Hd, Wd\) = \(30, 40\)"):
        DepthObservation(torch.zeros(30, 40, 1), DEPTH)
    with pytest.raises(ValueError, match=r"DepthObservation.depth of shape \(40, 30\)"):
        DepthObservation(torch.zeros(40, 30), DEPTH)
    with pytest.raises(ValueError, match="floating-point"):
        DepthObservation(torch.zeros(30, 40, dtype=torch.int32), DEPTH)
    with pytest.raises(ValueError, match="min_depth < max_depth"):
        DepthConfig(min_depth=3.0, max_depth=2.0)


def test_rendered_depth_matches_a_particle_by_particle_ray_loop(world: ProceduralWorld, generator: torch.Generator) -> None:
    """Chunked, batched rendering against one ray at a time (camera-frame depth of the hit point; a miss counts c²)."""
    truth = true_pose(world)
    observation = _depth_image(world, truth)
    config = DepthConfig(pixels=40, truncation=0.3)
    pixels = sample_depth_pixels(observation, config, generator).double()
    poses = poses_around(truth, 6, math.radians(3), 0.1, generator)
    fast = rendered_depth_log_likelihoods(poses, observation, pixels, world.render_surface, config, ray_chunk=37)
    slow = []
    for pose in poses:
        predicted, observed = [], []
        for u, v in pixels.tolist():
            camera_direction = torch.tensor([(u - DEPTH.cx) / DEPTH.fx, -(v - DEPTH.cy) / DEPTH.fy, -1.0], dtype=torch.float64)
            _, point, opacity = world.render_surface(pose[None, :3, 3], (pose[:3, :3] @ camera_direction)[None])
            in_camera = pose_inverse(pose) @ torch.cat((point[0], torch.ones(1, dtype=torch.float64)))
            predicted.append(-float(in_camera[2]) if float(opacity[0]) >= 0.5 else math.nan)
            observed.append(float(observation.depth[int(v), int(u)]))
        slow.append(_naive_depth_log_likelihood(predicted, observed, config))
    torch.testing.assert_close(fast, torch.tensor(slow, dtype=torch.float64), rtol=1e-9, atol=1e-9)


def _naive_reading(depth: torch.Tensor, u: float, v: float, config: DepthConfig) -> float:
    """Bilinear among four valid neighbours within the truncation of each other, else the nearest valid pixel, else NaN."""
    height, width = depth.shape
    valid = lambda r, c: config.min_depth <= float(depth[r, c]) <= config.max_depth
    column, row = min(max(round(u), 0), width - 1), min(max(round(v), 0), height - 1)
    if not (0 <= round(u) <= width - 1 and 0 <= round(v) <= height - 1):
        return math.nan
    left, top = min(max(math.floor(u), 0), width - 2), min(max(math.floor(v), 0), height - 2)
    a, b = min(max(u - left, 0.0), 1.0), min(max(v - top, 0.0), 1.0)
    corners = [(top, left), (top, left + 1), (top + 1, left), (top + 1, left + 1)]
    readings = [float(depth[r, c]) for r, c in corners]
    if all(valid(r, c) for r, c in corners) and max(readings) - min(readings) <= config.truncation:
        weights = [(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b]
        return sum(w * r for w, r in zip(weights, readings))
    return float(depth[row, column]) if valid(row, column) else math.nan


def test_warped_depth_matches_a_particle_by_particle_projection_loop(generator: torch.Generator) -> None:
    """Projection into each particle's depth camera, bilinear or nearest-pixel reading; behind, outside, invalid or at infinity counts c²."""
    depth = 2.0 + 0.2 * torch.rand(DEPTH.height, DEPTH.width, generator=generator)
    depth[10:20, 5:15] += 1.0  # a depth edge
    depth[::3, ::4] = 0.0  # holes
    observation = DepthObservation(depth, DEPTH)
    config = DepthConfig(truncation=0.5)
    points = torch.cat(
        (
            torch.randn(60, 3, generator=generator, dtype=torch.float64) * torch.tensor([1.0, 1.0, 0.5], dtype=torch.float64),
            torch.ones(60, 1, dtype=torch.float64),
        ),
        dim=-1,
    )
    points[:, 2] -= 2.5  # mostly in front of the identity camera (OpenGL: it looks along -z)
    points[0, 2] = 1.0  # behind
    points[1, 3] = 0.0  # a direction at infinity
    poses = poses_around(torch.eye(4, dtype=torch.float64), 5, math.radians(5), 0.2, generator)
    fast = warped_depth_log_likelihoods(poses, points, observation, config)
    slow = []
    for pose in poses:
        predicted, observed = [], []
        for point in points:
            x, y, z, _ = (pose_inverse(pose) @ point).tolist() if float(point[3]) != 0 else (0.0, 0.0, 0.0, 0.0)
            d = -z
            predicted.append(d)
            reading = math.nan
            if float(point[3]) != 0 and d > 1e-6:
                reading = _naive_reading(depth, DEPTH.cx + DEPTH.fx * x / d, DEPTH.cy - DEPTH.fy * y / d, config)
            observed.append(reading)
        slow.append(_naive_depth_log_likelihood(predicted, observed, config))
    torch.testing.assert_close(fast, torch.tensor(slow, dtype=torch.float64), rtol=1e-9, atol=1e-9)


def test_the_true_pose_is_the_most_likely_in_the_procedural_world(world: ProceduralWorld, generator: torch.Generator) -> None:
    """A depth image rendered at the truth: the truth scores highest among perturbed poses, rendered and re-projected."""
    truth = true_pose(world)
    observation = _depth_image(world, truth, FINE_DEPTH)
    config = DepthConfig(pixels=128)
    poses = torch.cat((truth[None], poses_around(truth, 40, math.radians(1.0), 0.03, generator)))
    rendered = rendered_depth_log_likelihoods(poses, observation, sample_depth_pixels(observation, config, generator), world.render_surface, config)
    assert int(rendered.argmax()) == 0
    measurement = preset("llff").measurement.model_copy(update={"warp": WarpConfig(max_spread=0.05), "depth": config})
    reference = render_reference(world.render_surface, truth, COLOUR, measurement, generator, config.pixels, FINE_DEPTH)
    assert reference.depth_points.shape == (config.pixels, 4)
    warped = warped_depth_log_likelihoods(poses, reference.depth_points, observation, config)
    assert int(warped.argmax()) == 0


def test_a_depth_camera_offset_from_the_colour_camera_is_where_the_depth_is_seen_from(world: ProceduralWorld, generator: torch.Generator) -> None:
    """With ``T_cam_depth`` set, a particle's depth term is the offset-free term of the particle times the offset
    (rendered and re-projected alike), and the true colour pose, not the depth camera's, scores highest."""
    offset = make_pose(so3_exp(torch.tensor([0.02, -0.01, 0.015], dtype=torch.float64)), torch.tensor([-0.03, 0.016, 0.004], dtype=torch.float64))
    truth = true_pose(world)
    seen = _depth_image(world, truth @ offset, FINE_DEPTH)
    observation = DepthObservation(seen.depth, FINE_DEPTH, offset)
    config = DepthConfig(pixels=128)
    poses = torch.cat((truth[None], poses_around(truth, 30, math.radians(1.0), 0.03, generator)))
    pixels = sample_depth_pixels(observation, config, generator)
    rendered = rendered_depth_log_likelihoods(poses, observation, pixels, world.render_surface, config)
    torch.testing.assert_close(rendered, rendered_depth_log_likelihoods(poses @ offset, seen, pixels, world.render_surface, config))
    assert int(rendered.argmax()) == 0
    measurement = preset("llff").measurement.model_copy(update={"warp": WarpConfig(max_spread=0.05), "depth": config})
    reference = render_reference(world.render_surface, truth, COLOUR, measurement, generator, config.pixels, FINE_DEPTH, offset)
    warped = warped_depth_log_likelihoods(poses, reference.depth_points, observation, config)
    torch.testing.assert_close(warped, warped_depth_log_likelihoods(poses @ offset, reference.depth_points, seen, config))
    assert int(warped.argmax()) == 0
    scaled = observation.scaled(2.0)
    torch.testing.assert_close(scaled.T_cam_depth[:3, 3], 2.0 * offset[:3, 3])
    torch.testing.assert_close(scaled.T_cam_depth[:3, :3], offset[:3, :3])
    with pytest.raises(ValueError, match="T_cam_depth of shape"):
        DepthObservation(seen.depth, FINE_DEPTH, torch.eye(3))


def _localizer(depth: DepthConfig | None, warp: WarpConfig | None = None, particles: int = 50) -> Localizer:
    config = preset("llff", particles=particles)
    config = config.model_copy(update={"measurement": config.measurement.model_copy(update={"pixels": 16, "depth": depth, "warp": warp})})
    return Localizer(config, torch.Generator().manual_seed(0))


def test_localizer_adds_the_depth_term(world: ProceduralWorld) -> None:
    """Depth configured and given: N × (M + M_d) rays, or the reference's alone when warping; refused without a
    surface renderer; a frame without depth is colour only; depth not configured leaves the update exactly as it was."""
    truth = true_pose(world)
    image = world.render_image(truth.float(), COLOUR)
    observation = _depth_image(world, truth)
    spread = torch.diag(torch.tensor([1e-3] * 3 + [1e-2] * 3, dtype=torch.float64))
    localizer = _localizer(DepthConfig(pixels=24))
    localizer.initialize_gaussian(truth, spread)
    assert localizer.update(image, COLOUR, world.render_rays, world.render_surface, observation).rays == 50 * (16 + 24)
    with pytest.raises(ValueError, match=r"measurement.depth is set but the map cannot place surfaces"):
        localizer.update(image, COLOUR, world.render_rays, None, observation)
    assert localizer.update(image, COLOUR, world.render_rays, world.render_surface).rays == localizer.particles.count * 16

    runs = []
    for depth_config, observation_given in ((None, None), (None, observation)):
        plain = _localizer(depth_config)
        plain.initialize_gaussian(truth, spread)
        plain.update(image, COLOUR, world.render_rays, world.render_surface, observation_given)
        runs.append(plain.particles.poses.clone())
    torch.testing.assert_close(runs[0], runs[1], rtol=0, atol=0)

    warping = _localizer(DepthConfig(pixels=24), WarpConfig(max_spread=0.05, pixels=40), particles=200)
    warping.initialize_gaussian(truth, torch.diag(torch.tensor([1e-5] * 3 + [1e-5] * 3, dtype=torch.float64)))
    assert warping.update(image, COLOUR, world.render_rays, world.render_surface, observation).rays == 32 * 24  # the reference at stride 2


@pytest.fixture(scope="module")
def surface_layer(world: ProceduralWorld) -> SurfaceDistance:
    """The layer of exact depth images seen from the true pose and eight poses around it (2 cm vertices)."""
    truth = true_pose(world)
    poses = torch.cat((truth[None], poses_around(truth, 8, math.radians(8.0), 0.3, torch.Generator().manual_seed(9))))
    depths = torch.stack([_depth_image(world, pose, FINE_DEPTH).depth for pose in poses])
    return SurfaceDistance.from_points(depth_points(depths, poses, FINE_DEPTH), SurfaceDistanceConfig(voxel=0.02, truncation=0.06))


def test_surface_distance_likelihood_matches_a_point_by_point_loop(world: ProceduralWorld, surface_layer: SurfaceDistance, generator: torch.Generator) -> None:
    """Batched placement of the depth points against one particle and one pixel at a time in float64
    (p = D(q) · K⁻¹q̃, placed by the depth camera's pose, its distance looked up alone), with a depth camera offset."""
    offset = make_pose(so3_exp(torch.tensor([0.02, -0.01, 0.015], dtype=torch.float64)), torch.tensor([-0.03, 0.016, 0.004], dtype=torch.float64))
    truth = true_pose(world)
    observation = DepthObservation(_depth_image(world, truth @ offset, FINE_DEPTH).depth, FINE_DEPTH, offset)
    config = DepthConfig(pixels=30, truncation=0.05, exponent=8.0, likelihood="surface_distance")
    poses = torch.cat((truth[None], poses_around(truth, 6, math.radians(2.0), 0.05, generator)))
    pixels = sample_depth_pixels(observation, config, generator)
    fast = surface_distance_log_likelihoods(poses, observation, pixels, surface_layer, config)
    slow = []
    for pose in poses:
        depth_pose = pose @ offset
        residuals = []
        for u, v in pixels.tolist():
            reading = float(observation.depth[int(v), int(u)])
            x, y = (u - FINE_DEPTH.cx) / FINE_DEPTH.fx, -(v - FINE_DEPTH.cy) / FINE_DEPTH.fy
            point = depth_pose[:3, :3] @ torch.tensor([x, y, -1.0], dtype=torch.float64) * reading + depth_pose[:3, 3]
            residuals.append(float(surface_layer(point[None])[0]))
        slow.append(_naive_depth_log_likelihood(residuals, [0.0] * len(residuals), config))
    torch.testing.assert_close(fast, torch.tensor(slow, dtype=torch.float64), rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(fast, surface_distance_log_likelihoods(poses.float(), observation, pixels, surface_layer, config), rtol=1e-4, atol=1e-3)


def test_the_true_pose_is_the_most_likely_by_surface_distance(world: ProceduralWorld, surface_layer: SurfaceDistance, generator: torch.Generator) -> None:
    """A depth image rendered at the truth: the truth scores highest among 40 poses 1° and 3 cm around it."""
    truth = true_pose(world)
    observation = _depth_image(world, truth, FINE_DEPTH)
    config = DepthConfig(pixels=128, truncation=0.05, likelihood="surface_distance")
    poses = torch.cat((truth[None], poses_around(truth, 40, math.radians(1.0), 0.03, generator)))
    scores = surface_distance_log_likelihoods(poses, observation, sample_depth_pixels(observation, config, generator), surface_layer, config)
    assert int(scores.argmax()) == 0


def test_localizer_looks_depth_up_in_the_surface_distance_layer(world: ProceduralWorld, surface_layer: SurfaceDistance) -> None:
    """``likelihood = "surface_distance"``: no depth rays are rendered (N × M colour rays; the reference alone when
    warping), no surface renderer is needed for it, and a map without the layer is refused naming the fix."""
    truth = true_pose(world)
    image = world.render_image(truth.float(), COLOUR)
    observation = _depth_image(world, truth)
    spread = torch.diag(torch.tensor([1e-3] * 3 + [1e-2] * 3, dtype=torch.float64))
    localizer = _localizer(DepthConfig(pixels=24, likelihood="surface_distance"))
    localizer.initialize_gaussian(truth, spread)
    assert localizer.update(image, COLOUR, world.render_rays, None, observation, surface_layer).rays == 50 * 16
    with pytest.raises(ValueError, match=r"likelihood is 'surface_distance' but the map has no surface-distance layer"):
        localizer.update(image, COLOUR, world.render_rays, world.render_surface, observation)
    warping = _localizer(DepthConfig(pixels=24, likelihood="surface_distance"), WarpConfig(max_spread=0.05, pixels=40), particles=200)
    warping.initialize_gaussian(truth, torch.diag(torch.tensor([1e-5] * 3 + [1e-5] * 3, dtype=torch.float64)))
    assert (
        warping.update(image, COLOUR, world.render_rays, world.render_surface, observation, surface_layer).rays == 32 * 24
    )  # the colour reference at stride 2, no depth points
