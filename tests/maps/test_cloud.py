"""The map as occupied voxels (locnerf.maps.cloud), against float64 oracles and the world's exact geometry."""

from __future__ import annotations

import math
import types

import pytest
import torch

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, so3_exp
from locnerf.maps.cloud import map_cloud, points_to_metric, voxel_cloud
from locnerf.sim.world import ProceduralWorld


def test_voxel_cloud_keeps_one_centre_per_occupied_cube_with_the_mean_colour() -> None:
    points = torch.tensor([[0.1, 0.1, 0.1], [0.4, 0.2, 0.3], [1.2, 0.1, 0.1], [-0.1, 0.0, 0.0]], dtype=torch.float64)
    colours = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.5]], dtype=torch.float64)
    centres, mean = voxel_cloud(points, colours, 0.5)
    # Cubes of edge 0.5 aligned to the origin: (-1, 0, 0), (0, 0, 0) holding two points, (2, 0, 0).
    torch.testing.assert_close(centres, torch.tensor([[-0.25, 0.25, 0.25], [0.25, 0.25, 0.25], [1.25, 0.25, 0.25]], dtype=torch.float64))
    torch.testing.assert_close(mean, torch.tensor([[0.5, 0.5, 0.5], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64))
    with pytest.raises(ValueError, match="voxel=0"):
        voxel_cloud(points, colours, 0.0)


def test_points_to_metric_inverts_the_map_normalization() -> None:
    turn = make_pose(so3_exp(torch.tensor([0.3, -0.5, 0.2], dtype=torch.float64)), torch.tensor([1.0, 2.0, -3.0], dtype=torch.float64))
    normalization = MapNormalization(T_map_dataset=turn.tolist(), scale=0.37)
    metric = torch.randn(20, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 3
    # Oracle: the points as the translations of poses, through the normalization's own pose conversion.
    poses = torch.eye(4, dtype=torch.float64).repeat(20, 1, 1)
    poses[:, :3, 3] = metric
    in_map = normalization.metric_to_map(poses)[:, :3, 3]
    torch.testing.assert_close(points_to_metric(in_map, normalization), metric, atol=1e-12, rtol=0)


def distance_to_world_surfaces(world: ProceduralWorld, points: torch.Tensor) -> torch.Tensor:
    """(P,) distance of points (P, 3) to the nearest wall, floor, ceiling or box face, float64."""
    p = points.double()
    walls = torch.minimum((p - world.room_min).abs(), (world.room_max - p).abs()).amin(-1)
    low, high = world.box_min[None], world.box_max[None]  # (1, B, 3)
    q = p[:, None]
    outside = torch.clamp(torch.maximum(low - q, q - high), min=0).norm(dim=-1)  # (P, B)
    inside = torch.minimum(q - low, high - q).amin(-1).clamp(min=0)
    boxes = torch.where(outside > 0, outside, inside).amin(-1)
    return torch.minimum(walls, boxes)


def test_the_worlds_cloud_lies_on_its_surfaces_and_spans_the_room_below_the_cameras() -> None:
    world = ProceduralWorld.default()
    cloud = map_cloud(world, views=6, width=40, voxels_across=60)
    assert cloud.points.dtype == torch.float32 and cloud.colours.dtype == torch.uint8 and cloud.colours.shape == cloud.points.shape
    assert len(cloud.points) > 1000 and cloud.up == pytest.approx((0.0, 1.0, 0.0))
    # Room 8 m across over 60 voxels; every voxel centre is within half a voxel diagonal of a surface point.
    assert cloud.voxel == pytest.approx(8.0 / 60, rel=0.02)
    distance = distance_to_world_surfaces(world, cloud.points)
    assert float(distance.max()) <= math.sqrt(3) / 2 * cloud.voxel + 1e-5
    low, high = cloud.points.amin(0).double(), cloud.points.amax(0).double()
    assert (low <= world.room_min + cloud.voxel).all() and (high[[0, 2]] >= world.room_max[[0, 2]] - cloud.voxel).all()
    # The ceiling (3 m) is cut: nothing above the highest camera (2.2 m) but the voxel holding it.
    top = float(world.camera_bounds()[1, 1])
    assert top + cloud.voxel >= float(high[1]) >= top - cloud.voxel
    uncut = map_cloud(world, views=3, width=32, voxels_across=60, cut_above_cameras=False)
    assert float(uncut.points[:, 1].max()) >= float(world.room_max[1]) - uncut.voxel
    # The textures are not flat: the voxels differ in colour.
    assert float(cloud.colours.float().std(0).min()) > 5


def test_a_map_that_cannot_place_its_surfaces_is_refused() -> None:
    ndc_map = types.SimpleNamespace(normalization=MapNormalization(ndc=True), render_surface=lambda o, d: None)
    with pytest.raises(LocnerfInputError, match="ndc=True"):
        map_cloud(ndc_map)
