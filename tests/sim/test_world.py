"""The procedural world: exact ray casting, determinism, a likelihood basin, bad input."""

from __future__ import annotations

import pytest
import torch

from locnerf.field.protocol import RadianceMap
from locnerf.geometry import make_pose, so3_exp
from locnerf.sim.benchmark import benchmark_world
from locnerf.sim.world import ProceduralWorld, WorldConfig


@pytest.fixture(scope="module")
def empty_room() -> ProceduralWorld:
    return ProceduralWorld(WorldConfig(boxes=0))


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


def test_rays_hit_the_walls_of_an_empty_room_at_hand_worked_distances(empty_room):
    # Room 8 × 3 × 8 m centred on x = z = 0, floor at y = 0. From (1, 1.5, 0):
    origins = torch.tensor([[1.0, 1.5, 0.0]] * 4, dtype=torch.float64)
    directions = torch.tensor([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -2.0], [-1.0, 1.0, 0]], dtype=torch.float64)
    t, surface = empty_room.cast(origins, directions)
    assert torch.allclose(t, torch.tensor([3.0, 1.5, 2.0, 1.5], dtype=torch.float64))
    # Surface ids: axis * 2 + side (side 1 = the max face).
    assert surface.tolist() == [1, 2, 4, 3]


def test_a_box_in_front_occludes_the_wall():
    world = ProceduralWorld(WorldConfig(boxes=1))
    world.box_min = torch.tensor([[-0.5, 0.0, 1.0]], dtype=torch.float64)
    world.box_max = torch.tensor([[0.5, 1.0, 2.0]], dtype=torch.float64)
    origins = torch.tensor([[0.0, 0.5, 0.0], [0.0, 1.5, 0.0], [0.0, 0.5, 1.5]], dtype=torch.float64)
    directions = torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=torch.float64)
    t, surface = world.cast(origins, directions)
    # Hits the box face at z = 1; passes over it to the wall at z = 4; starts inside it: wall.
    assert torch.allclose(t, torch.tensor([1.0, 4.0, 2.5], dtype=torch.float64))
    assert surface.tolist() == [6, 5, 5]


def test_world_satisfies_the_radiance_map_protocol(world):
    assert isinstance(world, RadianceMap)
    assert world.samples_per_ray == 1
    bounds = world.camera_bounds()
    assert bounds.shape == (2, 3) and (bounds[1] > bounds[0]).all()


def test_rendering_is_deterministic_and_in_range(world):
    pose = world.sample_camera_pose(torch.Generator().manual_seed(5))
    a = world.render_image(pose)
    b = ProceduralWorld.default().render_image(pose)
    assert torch.equal(a, b)
    assert a.shape == (world.default_intrinsics.height, world.default_intrinsics.width, 3)
    assert a.min() >= 0 and a.max() <= 1 and a.std() > 0.05


def test_float32_and_float64_renders_agree(world):
    pose = world.sample_camera_pose(torch.Generator().manual_seed(6))
    high = world.render_image(pose.double())
    low = world.render_image(pose.float())
    # Float32 ray parameters move edge pixels by at most one pixel: compare the bulk.
    assert (high.float() - low).abs().median() < 1e-4


def test_nearby_poses_give_more_similar_images_than_distant_ones(world):
    """The basin that makes the particle filter work: error grows with the pose offset."""
    generator = torch.Generator().manual_seed(8)
    errors = {0.05: [], 0.5: []}
    for _ in range(6):
        pose = world.sample_camera_pose(generator)
        reference = world.render_image(pose)
        for offset in errors:
            moved = pose @ make_pose(so3_exp(torch.tensor([0.0, offset / 2, 0.0], dtype=torch.float64)), torch.tensor([offset, 0.0, 0.0], dtype=torch.float64))
            errors[offset].append(float(((world.render_image(moved) - reference) ** 2).mean()))
    # Tolerance: every small offset beats the mean large offset by a factor of two.
    assert max(errors[0.05]) * 2 < sum(errors[0.5]) / len(errors[0.5])


def test_sampled_camera_poses_are_free_and_see_a_surface_ahead(world):
    generator = torch.Generator().manual_seed(9)
    for _ in range(20):
        pose = world.sample_camera_pose(generator)
        assert world.is_free(pose[None, :3, 3], clearance=0.3).item()
        depth, _ = world.cast(pose[None, :3, 3], -pose[None, :3, 2])
        assert depth.item() >= 1.0


def test_bad_rays_and_poses_are_refused(world):
    with pytest.raises(ValueError, match=r"\(R, 3\)"):
        world.render_rays(torch.zeros(4, 2), torch.zeros(4, 2))
    with pytest.raises(ValueError, match="NaN"):
        world.render_image(torch.full((4, 4), float("nan")))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        world.is_free(torch.zeros(3))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_render_matches_the_cpu_render(world):
    pose = world.sample_camera_pose(torch.Generator().manual_seed(10))
    cpu = world.render_image(pose)
    cuda = ProceduralWorld.default("cuda").render_image(pose.cuda()).cpu()
    assert (cpu - cuda).abs().median() < 1e-5


def test_benchmark_reports_both_dtypes_and_refuses_zero_rays():
    rows = benchmark_world(rays=128, repeats=1, device=torch.device("cpu"))
    assert [row["dtype"] for row in rows] == ["float32", "float64"] and all(row["median_ms"] > 0 for row in rows)
    with pytest.raises(ValueError, match="rays"):
        benchmark_world(rays=0, repeats=1, device=torch.device("cpu"))
