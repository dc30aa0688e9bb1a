"""TUM / EuRoC trajectory files: round trip, both formats, stamp matching, and every refusal names file and line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from locnerf.data.trajectory_files import read_trajectory, sample_trajectory, trajectory_format, write_tum
from locnerf.errors import DatasetError, LocnerfInputError


def random_poses(count: int, seed: int) -> torch.Tensor:
    """(count, 4, 4) float64 rigid poses from scipy (an independent quaternion implementation)."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (count, 1, 1))
    poses[:, :3, :3] = Rotation.random(count, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(count, 3))
    return torch.from_numpy(poses)


def test_tum_round_trip_matches_scipy_quaternions(tmp_path: Path) -> None:
    poses = random_poses(20, 0)
    stamps = 1305031102.175304 + np.arange(20) / 30.0
    path = write_tum(tmp_path / "t.txt", stamps, poses)
    rows = np.loadtxt(path)
    # The file's quaternions, read by scipy (x, y, z, w), give the written rotations.
    assert np.allclose(Rotation.from_quat(rows[:, 4:8]).as_matrix(), poses[:, :3, :3].numpy(), atol=1e-8)
    back = read_trajectory(path)
    assert trajectory_format(path) == "tum"
    assert np.allclose(back.stamps, stamps, atol=1e-6)
    assert torch.allclose(back.poses, poses, atol=1e-8)
    assert back.lines == list(range(2, 22))


def test_euroc_csv_with_extra_columns(tmp_path: Path) -> None:
    poses = random_poses(5, 1)
    quaternions = Rotation.from_matrix(poses[:, :3, :3].numpy()).as_quat()  # x, y, z, w
    lines = ["#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_x, v_y, v_z"]
    for k in range(5):
        p, q = poses[k, :3, 3].tolist(), quaternions[k]
        lines.append(f"{1403636579763555584 + k * 50_000_000}, {p[0]}, {p[1]}, {p[2]}, {q[3]}, {q[0]}, {q[1]}, {q[2]}, 0.1, 0.2, 0.3")
    path = tmp_path / "vins.csv"
    path.write_text("\n".join(lines) + "\n")
    trajectory = read_trajectory(path)
    assert trajectory_format(path) == "euroc"
    assert np.allclose(np.diff(trajectory.stamps), 0.05, atol=1e-6)
    assert torch.allclose(trajectory.poses, poses, atol=1e-9)


def test_sample_trajectory_exact_interpolated_and_gaps(tmp_path: Path) -> None:
    poses = random_poses(4, 2)
    stamps = np.array([0.0, 0.1, 0.2, 1.0])
    trajectory = read_trajectory(write_tum(tmp_path / "t.txt", stamps, poses))
    sampled, valid = sample_trajectory(trajectory, np.array([0.1, 0.15, 0.5, 2.0]), max_gap=0.2)
    assert valid.tolist() == [True, True, False, False]
    assert torch.allclose(sampled[0], poses[1], atol=1e-8)
    # Halfway along the geodesic: the position is the chord's midpoint only for pure translations, so check with the relative motion.
    step = torch.linalg.inv(poses[1]) @ poses[2]
    half = torch.linalg.inv(poses[1]) @ sampled[1]
    assert math.isclose(Rotation.from_matrix(half[:3, :3].numpy()).magnitude() * 2, Rotation.from_matrix(step[:3, :3].numpy()).magnitude(), rel_tol=1e-6)
    with pytest.raises(DatasetError, match=r"t\.txt: stamps 0\.000000–1\.000000 s \(lines 2–5\) never overlap the images' stamps 5\.0"):
        sample_trajectory(trajectory, np.array([5.0, 6.0]), max_gap=0.2)


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (["0.0 0 0 0 0 0 0 1", "0.2 0 0 0 0 0 0 1", "0.1 0 0 0 0 0 0 1"], r"line 3: stamp 0\.1 s is before line 2's 0\.2 s; expected strictly increasing"),
        (["0.0 0 0 0 0 0 0 1", "0.0 0 0 0 0 0 0 1"], r"line 2: stamp 0\.0 s is a duplicate of line 1's 0\.0 s"),
        (["0.0 0 0 0 0 0 0 1", "0.1 0 0 0 0 0 0.1 1"], r"line 2: quaternion .* has norm 1\.004988; expected a unit quaternion"),
        (["0.0 0 0 0 0 0 0 0"], r"line 1: quaternion .* has norm 0\.000000; expected a unit quaternion"),
        (["0.0 0 0 0 0 0 1"], r"line 1: 7 fields, expected 8 whitespace-separated numbers"),
        (["0.0 0 0 nan 0 0 0 1"], r"line 1: a NaN or infinite value"),
        (["# only a comment"], r"no pose lines"),
    ],
)
def test_bad_tum_files_are_refused_naming_file_and_line(tmp_path: Path, lines: list[str], message: str) -> None:
    path = tmp_path / "odom.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=message) as caught:
        read_trajectory(path)
    assert str(path) in str(caught.value)


def test_bad_euroc_line_and_format_name(tmp_path: Path) -> None:
    path = tmp_path / "odom.csv"
    path.write_text("#ns,px,py,pz,qw,qx,qy,qz\n100,0,0,0,1,0,0,0\n200,0,0,0,1,0\n")
    with pytest.raises(DatasetError, match=r"odom\.csv, line 3: 6 fields, expected at least 8 comma-separated"):
        read_trajectory(path)
    with pytest.raises(LocnerfInputError, match=r"odometry format 'kitti': expected one of auto, tum, euroc"):
        read_trajectory(path, "kitti")
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_trajectory(tmp_path / "missing.txt")
