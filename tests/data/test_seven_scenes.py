"""7-Scenes reader: layout, splits, camera axes, depth, and the refusals of bad input (tiny fake scenes)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from locnerf.data import dataset_format, read_dataset, read_seven_scenes
from locnerf.data.seven_scenes import COLOUR_INTRINSICS, depth_points
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.render.camera import PinholeIntrinsics

WIDTH, HEIGHT = 8, 6
CAMERA = PinholeIntrinsics(fx=6.0, fy=6.0, cx=4.0, cy=3.0, width=WIDTH, height=HEIGHT)


def _pose(index: int) -> np.ndarray:
    angle = 0.1 * index
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    pose[:3, 3] = [0.1 * index, -0.2, 0.05 * index]
    return pose


def _write_frame(sequence: Path, number: int, depth_size: tuple[int, int] = (WIDTH // 2, HEIGHT // 2)) -> None:
    stem = sequence / f"frame-{number:06d}"
    colour = np.full((HEIGHT, WIDTH, 3), 10 * number % 256, np.uint8)
    cv2.imwrite(f"{stem}.color.png", colour)
    depth = np.full((depth_size[1], depth_size[0]), 1000 + 100 * number, np.uint16)
    depth[0, 0] = 0  # invalid reading
    cv2.imwrite(f"{stem}.depth.png", depth)
    np.savetxt(f"{stem}.pose.txt", _pose(number))


def _fake_scene(root: Path, frames: dict[int, range] | None = None) -> Path:
    """Two sequences (1: train, 2: test) of 3 frames each, colour 8x6, depth 4x3."""
    frames = frames or {1: range(0, 3), 2: range(3, 6)}
    for sequence, numbers in frames.items():
        folder = root / f"seq-{sequence:02d}"
        folder.mkdir(parents=True)
        for number in numbers:
            _write_frame(folder, number)
    (root / "TrainSplit.txt").write_text("sequence1\n")
    (root / "TestSplit.txt").write_text("sequence2\n")
    return root


def test_reads_splits_axes_depth_and_cameras(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    assert dataset_format(root) == "seven_scenes"
    train = read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)
    test = read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)
    assert train.names == ["seq-01/frame-000000", "seq-01/frame-000001", "seq-01/frame-000002"]
    assert len(test) == 3 and set(train.indices).isdisjoint(test.indices)
    assert train.images.shape == (3, 3, 4, 3)
    # Area-halved 8x6 colour: f/2, (c + 0.5)/2 - 0.5 (pixel centres at integers).
    assert (train.intrinsics.fx, train.intrinsics.cx, train.intrinsics.cy, train.intrinsics.width) == (3.0, 1.75, 1.25, 4)
    expected = opencv_to_opengl(torch.from_numpy(np.stack([_pose(i) for i in range(3)])))
    torch.testing.assert_close(train.T_world_cam, expected)
    torch.testing.assert_close(train.images[1], torch.full((3, 4, 3), 10 / 255))
    # Depth stays at its own 4x3 grid, metres, 0 where invalid, with the depth camera (585 px at 8 px wide
    # is the fallback focal, for a colour camera whose full size is 8x6, halved for the 4x3 depth).
    assert train.depths.shape == (3, 3, 4)
    assert float(train.depths[2, 1, 1]) == pytest.approx(1.2)
    assert float(train.depths[2, 0, 0]) == 0.0
    assert train.depth_intrinsics.width == 4 and train.depth_intrinsics.fx == pytest.approx(585.0 / 2)
    assert (train.depth_intrinsics.cx, train.depth_intrinsics.cy) == (2.0, 1.5)  # the 4x3 depth is every 2nd pixel of 8x6
    assert train.normalization.scale == 1.0 and train.normalization.up == (0.0, -1.0, 0.0)
    # The box holds every camera centre and every back-projected depth point.
    points = depth_points(train.depths, train.T_world_cam, train.depth_intrinsics)
    inside = torch.cat((points, train.T_world_cam[:, :3, 3]))
    assert bool(((inside >= train.scene_bounds[0]) & (inside <= train.scene_bounds[1])).all())
    both = read_seven_scenes(root, split="all", downscale=2, stride=2, intrinsics=CAMERA)
    assert both.names == ["seq-01/frame-000000", "seq-01/frame-000002", "seq-02/frame-000004"]


def test_depth_points_lie_along_the_optical_axis() -> None:
    camera = PinholeIntrinsics(fx=2.0, fy=2.0, cx=1.0, cy=1.0, width=3, height=3)
    depths = torch.zeros(1, 3, 3)
    depths[0, 1, 1] = 2.5  # the principal point: straight ahead, along -z in OpenGL axes
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    points = depth_points(depths, pose[None], camera)
    torch.testing.assert_close(points, torch.tensor([[1.0, 2.0, 0.5]], dtype=torch.float64))


def test_gravity_file_gives_the_up_axis(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    (root / "gravity-direction.txt").write_text("0\n2\n0\n")
    assert read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA).normalization.up == (0.0, -1.0, 0.0)
    (root / "gravity-direction.txt").write_text("0\n0\n-1\n")
    assert read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA).normalization.up == (0.0, 0.0, 1.0)


def test_refuses_a_missing_pose(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    (root / "seq-01" / "frame-000001.pose.txt").unlink()
    with pytest.raises(FileNotFoundError, match=r"frame-000001\.pose\.txt.*4x4 camera-to-world"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_refuses_a_non_rigid_pose(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    sheared = _pose(2)
    sheared[0, 1] = 0.3
    np.savetxt(root / "seq-01" / "frame-000002.pose.txt", sheared)
    with pytest.raises(ValueError, match=r"frame-000002\.pose\.txt: not a rigid transform"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_nearly_rigid_poses_come_back_exactly_rigid(tmp_path: Path) -> None:
    """A rotation orthonormal to 4e-4 only (as printed in the real files, determinant ~0.9989) is
    accepted and replaced by the closest rotation; the last row becomes exactly 0 0 0 1."""
    root = _fake_scene(tmp_path / "scene")
    rounded = _pose(1)
    rounded[:3, :3] *= 1 - 4e-4
    rounded[3, 3] = 1 + 1e-5
    np.savetxt(root / "seq-01" / "frame-000001.pose.txt", rounded)
    poses = read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA).T_world_cam.double()
    rotations = poses[:, :3, :3]
    eye = torch.eye(3, dtype=torch.float64)
    assert float((rotations.transpose(-1, -2) @ rotations - eye).abs().max()) < 1e-6  # float32 storage
    assert torch.allclose(torch.linalg.det(rotations), torch.ones(3, dtype=torch.float64), atol=1e-6)
    assert float((poses[:, 3] - torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)).abs().max()) == 0.0
    expected = opencv_to_opengl(torch.from_numpy(_pose(1))[None])[0]
    assert float((rotations[1] - expected[:3, :3]).abs().max()) < 1e-6


def test_refuses_depth_that_is_not_an_integer_fraction_of_colour(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene", {1: range(0, 0), 2: range(3, 6)})
    _write_frame(root / "seq-01", 0, depth_size=(3, 3))
    with pytest.raises(ValueError, match=r"frame-000000\.depth\.png: depth 3x3, expected the colour size 8x6 divided by an integer"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_refuses_depth_of_mixed_sizes(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    _write_frame(root / "seq-01", 2, depth_size=(8, 6))
    with pytest.raises(ValueError, match=r"frame-000002\.depth\.png: depth of size 8x6, expected 4x3"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_refuses_colour_that_does_not_fit_the_intrinsics(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    with pytest.raises(ValueError, match=r"frame-000000\.color\.png: images about 8x6, expected 640x480"):
        read_seven_scenes(root, "train", downscale=1)


def test_refuses_an_empty_split(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    (root / "TestSplit.txt").write_text("\n")
    with pytest.raises(ValueError, match=r"TestSplit\.txt: empty split"):
        read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)
    (root / "TestSplit.txt").write_text("sequence2\n")
    for frame in (root / "seq-02").iterdir():
        frame.unlink()
    with pytest.raises(FileNotFoundError, match=r"seq-02: no frame-NNNNNN\.color"):
        read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)


def test_refuses_an_unknown_split(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    with pytest.raises(ValueError, match=r"split 'val': expected one of \['all', 'test', 'train'\] for a 7-Scenes folder") as refused:
        read_seven_scenes(root, "val", downscale=2, intrinsics=CAMERA)
    assert str(root) in str(refused.value)


def test_refuses_a_split_file_naming_something_else_than_a_sequence(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    (root / "TestSplit.txt").write_text("sequence2\nseq-03\n")
    with pytest.raises(ValueError, match=r"TestSplit\.txt: line 'seq-03', expected 'sequenceN'"):
        read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)
    (root / "TestSplit.txt").write_text("sequence3\n")
    with pytest.raises(FileNotFoundError, match=r"TestSplit\.txt names sequence3: folder .*seq-03 not found"):
        read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)
    (root / "TestSplit.txt").unlink()
    with pytest.raises(FileNotFoundError, match=r"TestSplit\.txt: no such file \(a 7-Scenes split file naming 'sequenceN' lines\)"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)  # every split reads both files (frame numbering)


@pytest.mark.parametrize(
    ("content", "expected"),
    [("1 0 0\n0 1 0\n0 0 1\n", r"expected a finite 4x4 matrix, got shape \(3, 3\)"), ("pose unknown\n", r"not a 4x4 table of numbers")],
)
def test_refuses_a_pose_file_that_is_not_a_4x4_matrix(tmp_path: Path, content: str, expected: str) -> None:
    root = _fake_scene(tmp_path / "scene")
    (root / "seq-02" / "frame-000004.pose.txt").write_text(content)
    with pytest.raises(ValueError, match=r"frame-000004\.pose\.txt: " + expected):
        read_seven_scenes(root, "test", downscale=2, intrinsics=CAMERA)


def test_refuses_colour_images_of_mixed_sizes(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    cv2.imwrite(str(root / "seq-01" / "frame-000001.color.png"), np.zeros((2 * HEIGHT, 2 * WIDTH, 3), np.uint8))
    with pytest.raises(ValueError, match=r"frame-000001\.color\.png has size 8x6: expected 4x3 like .*frame-000000\.color\.png"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_refuses_a_missing_or_non_millimetre_depth_image(tmp_path: Path) -> None:
    root = _fake_scene(tmp_path / "scene")
    depth = root / "seq-01" / "frame-000001.depth.png"
    depth.unlink()
    with pytest.raises(FileNotFoundError, match=r"frame-000001\.depth\.png: no such file or not an image \(the frame's uint16 depth in mm\)"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)
    cv2.imwrite(str(depth), np.full((HEIGHT // 2, WIDTH // 2), 200, np.uint8))
    with pytest.raises(ValueError, match=r"frame-000001\.depth\.png: uint8 image of shape \(3, 4\), expected single-channel uint16 millimetres"):
        read_seven_scenes(root, "train", downscale=2, intrinsics=CAMERA)


def test_real_redkitchen_frames(shared_data: Path) -> None:
    """A handful of real frames at 80x60: sizes, metric depth in the Kinect's range, gravity from the file."""
    kitchen = read_dataset(shared_data / "7scenes_redkitchen", split="test", downscale=8, stride=100)
    assert kitchen.names == [f"seq-02/frame-{n:06d}" for n in (600, 700, 800, 900)]
    assert kitchen.images.shape == (4, 60, 80, 3) and kitchen.depths.shape == (4, 60, 80)
    assert kitchen.intrinsics.fx == pytest.approx(525 / 8) and kitchen.depth_intrinsics.fx == pytest.approx(585 / 8)
    # Colour area-resized by 8: (320 + 0.5)/8 - 0.5 = 39.5625 (not 320/8 = 40); depth taken every 8th
    # pixel from camera-intrinsics.txt's (320, 240): pixel 0 stays pixel 0, so 320/8 = 40.
    assert (kitchen.intrinsics.cx, kitchen.intrinsics.cy) == (39.5625, 29.5625)
    assert (COLOUR_INTRINSICS.scaled(1 / 4).cx, COLOUR_INTRINSICS.scaled(1 / 4).cy) == (79.625, 59.625)  # the default ÷4
    assert (kitchen.depth_intrinsics.cx, kitchen.depth_intrinsics.cy) == (40.0, 30.0)
    valid = kitchen.depths[kitchen.depths > 0]
    assert 0.4 < float(valid.min()) and float(valid.max()) < 8.0 and len(valid) > 0.5 * kitchen.depths.numel()
    # The file's gravity (world frame) is nearly perpendicular to the hand-held camera's x axes (roll
    # stays small): |cos| < 0.3 (~17 degrees of roll) on every frame.
    up = torch.tensor(kitchen.normalization.up, dtype=torch.float64)
    assert float(up.norm()) == pytest.approx(1.0)
    assert float((kitchen.T_world_cam[:, :3, 0] @ up).abs().max()) < 0.3
