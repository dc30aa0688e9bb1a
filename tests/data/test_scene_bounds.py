"""Scene boxes of transforms.json data sets that are not object rings: points, depth, frusta, refusal."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from locnerf.data import read_nerfstudio
from locnerf.data.scene_bounds import read_ply_points, transforms_scene_box
from locnerf.errors import DatasetError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import camera_directions_from_pixels

WIDTH, HEIGHT, FOCAL = 40, 30, 30.0
WALL_DEPTH = 4.0
CAMERA = {"fl_x": FOCAL, "fl_y": FOCAL, "cx": (WIDTH - 1) / 2, "cy": (HEIGHT - 1) / 2, "w": WIDTH, "h": HEIGHT}


def _room_poses() -> np.ndarray:
    """(6, 4, 4) cameras spread over 1 m in x (0.6 m in y) at z = 0, all looking along -z at the wall z = -4."""
    poses = np.tile(np.eye(4), (6, 1, 1))
    poses[:, 0, 3] = np.linspace(-0.5, 0.5, 6)
    poses[:, 1, 3] = [-0.3, 0.3, -0.3, 0.3, -0.3, 0.3]
    return poses


def _wall_points_seen(poses: np.ndarray) -> torch.Tensor:
    """(K·4, 3) the wall points at the corner pixels of every camera (the extremes of what the cameras see of it)."""
    camera = PinholeIntrinsics(fx=FOCAL, fy=FOCAL, cx=CAMERA["cx"], cy=CAMERA["cy"], width=WIDTH, height=HEIGHT)
    corners = torch.tensor([[0.0, 0.0], [WIDTH - 1, 0.0], [0.0, HEIGHT - 1], [WIDTH - 1, HEIGHT - 1]])
    local = camera_directions_from_pixels(corners.double(), camera) * WALL_DEPTH
    return torch.cat([local + torch.from_numpy(pose[:3, 3]) for pose in poses])


def _write_room(folder: Path, extra: dict, depth: bool = False) -> Path:
    """A transforms.json of the room cameras with black 40×30 images (and uint16-mm depth of the wall when ``depth``)."""
    folder.mkdir(parents=True, exist_ok=True)
    frames = []
    for index, pose in enumerate(_room_poses()):
        cv2.imwrite(str(folder / f"frame_{index}.png"), np.zeros((HEIGHT, WIDTH, 3), np.uint8))
        frame = {"file_path": f"frame_{index}.png", "transform_matrix": pose.tolist()}
        if depth:  # half-size depth images, as depth cameras often are
            cv2.imwrite(str(folder / f"depth_{index}.png"), np.full((HEIGHT // 2, WIDTH // 2), WALL_DEPTH * 1000, np.uint16))
            frame["depth_file_path"] = f"depth_{index}.png"
        frames.append(frame)
    path = folder / "transforms.json"
    path.write_text(json.dumps({**CAMERA, **extra, "frames": frames}))
    return path


def _write_wall_ply(path: Path, binary: bool) -> None:
    """A PLY of wall points (x, y over what the cameras see, z = -4) with colour, as ns-process-data writes (ASCII) or 3DGS (binary)."""
    x, y = np.meshgrid(np.linspace(-3.0, 3.0, 31), np.linspace(-2.0, 2.0, 21))
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, -WALL_DEPTH)], axis=1).astype(np.float32)
    kind = "binary_little_endian" if binary else "ascii"
    header = f"ply\nformat {kind} 1.0\nelement vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\n"
    header += "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    if binary:
        table = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
        table["x"], table["y"], table["z"] = points.T
        path.write_bytes(header.encode() + table.tobytes())
    else:
        path.write_text(header + "".join(f"{px:8f} {py:8f} {pz:8f} 10 20 30\n" for px, py, pz in points))


def _contains(box: torch.Tensor, points: torch.Tensor) -> bool:
    return bool(((points >= box[0]) & (points <= box[1])).all())


def test_depth_images_bound_a_wall_four_metres_away(tmp_path: Path) -> None:
    """Cameras over 1 m looking at a wall 4 m away: the box holds every wall point the cameras see. (The old box, the
    camera centres grown by half their spread, ended at z = -0.5.)"""
    views = read_nerfstudio(_write_room(tmp_path, {}, depth=True))
    assert _contains(views.scene_bounds, _wall_points_seen(_room_poses()))
    assert float(views.scene_bounds[1, 2]) < -3.5  # the box is the wall's, not the cameras'
    assert views.far > WALL_DEPTH and views.near == pytest.approx(0.05)


@pytest.mark.parametrize("binary", [False, True])
def test_sparse_points_bound_the_wall(tmp_path: Path, binary: bool) -> None:
    _write_wall_ply(tmp_path / "sparse_pc.ply", binary)
    views = read_nerfstudio(_write_room(tmp_path, {"ply_file_path": "sparse_pc.ply"}))
    points = read_ply_points(tmp_path / "sparse_pc.ply")
    assert points.shape == (31 * 21, 3) and float(points[:, 2].max()) == pytest.approx(-WALL_DEPTH)
    assert _contains(views.scene_bounds, points)
    assert _contains(views.scene_bounds, _wall_points_seen(_room_poses()))


def test_near_and_far_bound_the_camera_frusta(tmp_path: Path) -> None:
    views = read_nerfstudio(_write_room(tmp_path, {"near": 0.1, "far": 5.0}))
    assert _contains(views.scene_bounds, _wall_points_seen(_room_poses()))
    assert float(views.scene_bounds[0, 2]) == pytest.approx(-5.0) and float(views.scene_bounds[1, 2]) == pytest.approx(-0.1)
    assert (views.near, views.far) == (0.1, 5.0)


def test_a_transforms_json_that_cannot_be_bounded_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="cannot bound the scene.*ply_file_path.*depth_file_path.*aabb.*near' and 'far'"):
        read_nerfstudio(_write_room(tmp_path / "none", {}))
    with pytest.raises(DatasetError, match="aabb"):
        read_nerfstudio(_write_room(tmp_path / "flat", {"aabb": [[0, 0, 0], [1, 1, 0]]}))
    with pytest.raises(DatasetError, match="near < far"):
        read_nerfstudio(_write_room(tmp_path / "inverted", {"near": 5.0, "far": 1.0}))


def test_an_object_ring_keeps_instant_ngps_cube(shared_data: Path) -> None:
    """lego's training cameras (a ring 4 units out) with instant-ngp's aabb_scale 1: the cube of edge 1/0.33 around the
    origin, which holds the object's [-1.5, 1.5]³; ``offset`` and ``scale`` move and size it as instant-ngp does."""
    lego = shared_data / "nerf_synthetic" / "lego"
    content = json.loads((lego / "transforms_train.json").read_text())
    poses = np.stack([np.asarray(frame["transform_matrix"]) for frame in content["frames"]])
    camera = PinholeIntrinsics.from_fov(800, 800, content["camera_angle_x"])
    box, near, far = transforms_scene_box({**content, "aabb_scale": 1}, lego / "transforms.json", content["frames"], poses, camera)
    torch.testing.assert_close(box, torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64) * 0.5 / 0.33)
    assert near == pytest.approx(0.05) and far == pytest.approx(float(np.linalg.norm(poses[:, :3, 3], axis=1).max()) + math.sqrt(3) * 0.5 / 0.33, rel=0.2)
    moved, _, _ = transforms_scene_box({**content, "aabb_scale": 2, "scale": 0.5, "offset": [0.5, 0.0, 0.5]}, lego, content["frames"], poses, camera)
    torch.testing.assert_close(moved, torch.tensor([[-2.0, -1.0, -2.0], [2.0, 3.0, 2.0]], dtype=torch.float64))
