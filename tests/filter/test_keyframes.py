"""Place recognition against the map: thumbnails, descriptors, queries, spacing (procedural world)."""

from __future__ import annotations

import pytest
import torch

from locnerf.filter.keyframes import nearest_neighbour_spacing, thumbnail_descriptors, thumbnail_shape
from locnerf.geometry import make_pose, se3_exp
from locnerf.maps.keyframes import build_keyframe_index
from locnerf.sim.world import ProceduralWorld


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


@pytest.fixture(scope="module")
def keyframes(world: ProceduralWorld) -> torch.Tensor:
    generator = torch.Generator().manual_seed(5)
    return torch.stack([world.sample_camera_pose(generator) for _ in range(40)])


def test_an_image_seen_from_a_keyframe_finds_that_keyframe_first(world, keyframes):
    index = build_keyframe_index(world.render_rays, keyframes, world.default_intrinsics)
    assert len(index) == 40 and index.shape == thumbnail_shape(world.default_intrinsics, 16)
    for which in (3, 17, 31):
        nudge = se3_exp(torch.tensor([0.0, 0.01, 0.0, 0.02, 0.0, -0.02], dtype=torch.float64))  # 0.6° and 3 cm
        image = world.render_image(keyframes[which] @ nudge)
        poses, scores = index.query(image, 5)
        assert torch.equal(poses[0], keyframes[which])
        assert scores[0] > 0.9 and bool((scores[:-1] >= scores[1:]).all())


def test_descriptors_ignore_brightness_offset_and_contrast(generator):
    images = torch.rand(3, 24, 32, 3, dtype=torch.float64, generator=generator) * 0.5
    plain = thumbnail_descriptors(images, (6, 8))
    changed = thumbnail_descriptors(images * 1.7 + 0.1, (6, 8))
    torch.testing.assert_close(plain, changed)
    torch.testing.assert_close(plain.norm(dim=1), torch.ones(3, dtype=torch.float64))
    # Area averaging: a 4× smaller thumbnail of a 4×-repeated image is the original.
    small = torch.rand(1, 6, 8, 3, dtype=torch.float64, generator=generator)
    large = small.repeat_interleave(4, dim=1).repeat_interleave(4, dim=2)
    torch.testing.assert_close(thumbnail_descriptors(large, (6, 8)), thumbnail_descriptors(small, (6, 8)))


def test_spacing_is_the_median_nearest_neighbour_distance(generator):
    positions = torch.rand(30, 3, dtype=torch.float64, generator=generator) * 5
    naive = []
    for i in range(30):
        naive.append(min(float((positions[i] - positions[j]).norm()) for j in range(30) if j != i))
    assert nearest_neighbour_spacing(positions) == pytest.approx(float(torch.tensor(naive, dtype=torch.float64).median()), abs=1e-9)
    assert nearest_neighbour_spacing(positions[:1]) == 0.0


def test_the_index_knows_which_cameras_its_thumbnails_fit(world, keyframes):
    index = build_keyframe_index(world.render_rays, keyframes[:3], world.default_intrinsics, width=8, supersample=1)
    camera = world.default_intrinsics
    assert index.matches(camera) and index.matches(camera.scaled(0.5))  # same field of view, other size
    assert not index.matches(camera.model_copy(update={"fx": camera.fx * 1.2, "fy": camera.fy * 1.2}))


def test_bad_keyframes_and_queries_are_refused(world, keyframes):
    with pytest.raises(ValueError, match="keyframe poses"):
        build_keyframe_index(world.render_rays, torch.eye(4, dtype=torch.float64)[None, :3], world.default_intrinsics)
    with pytest.raises(ValueError, match="thumbnail width 1"):
        build_keyframe_index(world.render_rays, keyframes[:2], world.default_intrinsics, width=1)
    index = build_keyframe_index(world.render_rays, keyframes[:4], world.default_intrinsics, width=8, supersample=2)
    with pytest.raises(ValueError, match="query image"):
        index.query(torch.zeros(10, 10), 2)
    poses, _ = index.query(world.render_image(make_pose(keyframes[0, :3, :3], keyframes[0, :3, 3])), 10)
    assert poses.shape == (4, 4, 4)  # at most K
