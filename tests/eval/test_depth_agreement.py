"""The depth offset: a fit of depth points to a surface-distance layer finds the pose that placed them."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.eval.depth_agreement import fit_depth_to_surface, summary_of
from locnerf.field.surface_distance import SurfaceDistance, SurfaceDistanceConfig
from locnerf.geometry import make_pose, rotation_error_deg, se3_exp, translation_error
from locnerf.geometry.se3 import pose_inverse


def room_corner(generator: torch.Generator, per_plane: int) -> torch.Tensor:
    """(3 · per_plane, 3) points on the floor and two walls of a 2 m room corner (x = 0, y = 0, z = 0 planes): every
    pose direction is fixed by some plane."""
    planes = []
    for axis in range(3):
        points = torch.rand(per_plane, 3, generator=generator, dtype=torch.float64) * 2.0
        points[:, axis] = 0.0
        planes.append(points)
    return torch.cat(planes)


@pytest.fixture(scope="module")
def corner() -> tuple[torch.Tensor, SurfaceDistance]:
    """Readings (3000, 3) on the corner's planes, and a layer at 2 cm vertices built from another, denser draw on them."""
    generator = torch.Generator().manual_seed(7)
    layer = SurfaceDistance.from_points(room_corner(generator, 40000).float(), SurfaceDistanceConfig(voxel=0.02, truncation=0.06))
    return room_corner(generator, 1000), layer


def camera_at(position: list[float], target: list[float]) -> torch.Tensor:
    """A pose (4, 4) float64 at ``position`` looking at ``target`` (OpenGL axes: −z forward, y up towards +z of the world)."""
    eye, goal = torch.tensor(position, dtype=torch.float64), torch.tensor(target, dtype=torch.float64)
    back = (eye - goal) / (eye - goal).norm()
    right = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), back)
    right = right / right.norm()
    up = torch.linalg.cross(back, right)
    return make_pose(torch.stack((right, up, back), dim=1), eye)


@pytest.mark.parametrize("offset_cm, offset_deg", [(0.0, 0.0), (3.0, 2.0), (8.0, 4.0)])
def test_the_fit_returns_the_pose_that_placed_the_readings(corner, offset_cm, offset_deg):
    """Readings of the corner from a known pose, through a depth camera 2 cm beside the colour camera and turned
    1°: fitted from the truth and from starts 3 cm / 2° and 8 cm / 4° off, the pose lands within 2 mm and 0.1°."""
    points, layer = corner
    truth = camera_at([1.2, 1.0, 1.1], [0.3, 0.4, 0.2])
    T_cam_depth = make_pose(
        se3_exp(torch.tensor([0.0, math.radians(1.0), 0.0, 0.0, 0.0, 0.0], dtype=torch.float64))[:3, :3], torch.tensor([0.02, 0.0, 0.0], dtype=torch.float64)
    )
    local = points @ pose_inverse(truth @ T_cam_depth)[:3, :3].T + pose_inverse(truth @ T_cam_depth)[:3, 3]
    direction = torch.tensor([0.3, -0.5, 0.8, 0.6, 0.2, -0.77], dtype=torch.float64)
    direction[:3] *= math.radians(offset_deg) / direction[:3].norm()
    direction[3:] *= offset_cm / 100 / direction[3:].norm()
    fitted = fit_depth_to_surface(truth @ se3_exp(direction), local, T_cam_depth, layer)
    assert float(translation_error(fitted, truth)) < 0.002
    assert float(rotation_error_deg(fitted, truth)) < 0.1


def test_the_summary_counts_the_frames_within_3_cm_and_1_degree():
    rows = [{"name": str(i), "translation_m": t, "rotation_deg": r} for i, (t, r) in enumerate([(0.01, 0.5), (0.04, 0.5), (0.02, 1.5), (0.0, 0.0)])]
    summary = summary_of(rows)
    assert summary["frames"] == 4 and summary["within_3cm_1deg"] == 0.5
    assert summary["translation_median_m"] == pytest.approx(0.015) and summary["rotation_p90_deg"] == 1.5
    assert summary_of([]) == {"frames": 0}
