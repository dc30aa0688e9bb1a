"""Trajectory files of the field: TUM (``stamp tx ty tz qx qy qz qw``) and EuRoC/ASL CSV.

- **TUM** (the TUM RGB-D benchmark, ``evo``, ORB-SLAM3, OpenVINS): one pose per line, whitespace
  separated, ``stamp`` in seconds, position in metres, quaternion scalar-last; ``#`` starts a comment.
- **EuRoC** (ASL ``data.csv``, VINS-Fusion's and Kimera's output): comma separated,
  ``stamp_ns, px, py, pz, qw, qx, qy, qz`` then any further columns (velocities, biases), stamp in
  integer nanoseconds, quaternion scalar-first; ``#`` starts a comment (the header line).

Each line's pose is ``T_frame_body`` (body points into the trajectory's fixed frame). Reading checks
every line and refuses, naming the file and the line, what a filter must not be fed: a wrong
number of columns, a non-finite number, a quaternion that is not unit (``|‖q‖ - 1| >``
:data:`UNIT_TOLERANCE`; within it the quaternion is normalised, as printed digits demand), and
stamps that do not strictly increase (a duplicate is named as such). Writing produces TUM with
nanosecond-resolution stamps, which ``evo_ape tum`` and the TUM tools read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from locnerf.geometry.se3 import interpolate_pose
from locnerf.geometry.validation import validate_poses

TrajectoryFormat = Literal["tum", "euroc"]
FORMATS: tuple[str, ...] = ("auto", "tum", "euroc")
UNIT_TOLERANCE = 1e-3
"""Largest accepted deviation of a quaternion's norm from 1 (a file printing 6 digits is within 1e-5)."""
NANOSECONDS = 1_000_000_000


@dataclass(frozen=True)
class Trajectory:
    """A stamped pose sequence read from (or written to) a file.

    Attributes:
        stamps: (K,) float64 seconds, strictly increasing.
        poses: (K, 4, 4) float64 ``T_frame_body``, metres.
        lines: (K,) the 1-based line of each pose in its file (for messages).
        source: the file it came from.
    """

    stamps: np.ndarray
    poses: torch.Tensor
    lines: list[int]
    source: str

    def __len__(self) -> int:
        return len(self.stamps)


def trajectory_format(path: str | Path) -> TrajectoryFormat:
    """``euroc`` when the first data line is comma separated, else ``tum``.

    Raises:
        FileNotFoundError / DatasetError: no such file, or no data line.
    """
    for _, line in _data_lines(Path(path)):
        return "euroc" if "," in line else "tum"
    raise DatasetError(f"{path}: no pose lines (expected TUM 'stamp tx ty tz qx qy qz qw' or EuRoC 'stamp_ns, px, py, pz, qw, qx, qy, qz' lines)")


def read_trajectory(path: str | Path, file_format: str = "auto") -> Trajectory:
    """Read a TUM or EuRoC trajectory file (``file_format`` ``auto`` decides by :func:`trajectory_format`).

    Raises:
        FileNotFoundError: no such file.
        LocnerfInputError: an unknown format name.
        DatasetError: naming the file, the line and what was expected (see the module docstring).
    """
    path = Path(path)
    if file_format not in FORMATS:
        raise LocnerfInputError(f"odometry format {file_format!r}: expected one of {', '.join(FORMATS)}")
    kind = trajectory_format(path) if file_format == "auto" else file_format
    stamps, poses, lines = [], [], []
    for number, line in _data_lines(path):
        stamp, position, quaternion_wxyz = _parse_line(path, number, line, kind)
        if stamps and stamp <= stamps[-1]:
            what = "a duplicate of" if stamp == stamps[-1] else "before"
            raise DatasetError(f"{path}, line {number}: stamp {stamp!r} s is {what} line {lines[-1]}'s {stamps[-1]!r} s; expected strictly increasing stamps")
        stamps.append(stamp)
        poses.append((position, quaternion_wxyz))
        lines.append(number)
    if not stamps:
        raise DatasetError(f"{path}: no pose lines (expected {kind} lines)")
    matrices = torch.eye(4, dtype=torch.float64).repeat(len(poses), 1, 1)
    matrices[:, :3, :3] = quaternion_to_matrix(torch.tensor([q for _, q in poses], dtype=torch.float64))
    matrices[:, :3, 3] = torch.tensor([p for p, _ in poses], dtype=torch.float64)
    return Trajectory(np.asarray(stamps, dtype=np.float64), matrices, lines, str(path))


def write_tum(path: str | Path, stamps: np.ndarray | torch.Tensor | list[float], poses: torch.Tensor) -> Path:
    """Write ``poses`` (K, 4, 4) at ``stamps`` (K,) seconds as a TUM file (``#`` header, nanosecond stamps).

    Raises:
        ValueError: mismatched lengths, stamps not strictly increasing, or poses that are not rigid.
    """
    path = Path(path)
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    poses = torch.as_tensor(poses, dtype=torch.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) != len(stamps):
        raise ValueError(f"trajectory of {len(stamps)} stamps and poses of shape {tuple(poses.shape)}: expected (K,) stamps and (K, 4, 4) poses")
    if (np.diff(stamps) <= 0).any():
        raise ValueError(f"{path}: stamps must strictly increase to be written as a trajectory")
    if len(poses):
        validate_poses(poses, name=f"poses written to {path}")
    quaternions = matrix_to_quaternion(poses[:, :3, :3]).numpy()  # (K, 4) w, x, y, z
    positions = poses[:, :3, 3].numpy()
    rows = [f"{stamp:.9f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f} {q[0]:.9f}" for stamp, p, q in zip(stamps, positions, quaternions)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "".join(row + "\n" for row in rows))
    return path


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, stripped text) of the lines that are neither blank nor ``#`` comments."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (a TUM or EuRoC trajectory)")
    text = path.read_text(errors="replace")
    return [(i, line.strip()) for i, line in enumerate(text.splitlines(), start=1) if line.strip() and not line.lstrip().startswith("#")]


def _parse_line(path: Path, number: int, line: str, kind: str) -> tuple[float, list[float], list[float]]:
    """Stamp (s), position (3,) and quaternion (w, x, y, z) of one data line, checked."""
    if kind == "tum":
        fields, expected = line.split(), "8 whitespace-separated numbers 'stamp tx ty tz qx qy qz qw'"
        if len(fields) != 8:
            raise DatasetError(f"{path}, line {number}: {len(fields)} fields, expected {expected}")
    else:
        fields, expected = [f.strip() for f in line.split(",")], "at least 8 comma-separated numbers 'stamp_ns, px, py, pz, qw, qx, qy, qz'"
        if len(fields) < 8:
            raise DatasetError(f"{path}, line {number}: {len(fields)} fields, expected {expected}")
    try:
        values = [float(field) for field in fields[:8]]
    except ValueError as error:
        raise DatasetError(f"{path}, line {number}: {error}; expected {expected}") from error
    if not all(math.isfinite(v) for v in values):
        raise DatasetError(f"{path}, line {number}: a NaN or infinite value in {fields[:8]}; expected finite numbers")
    if kind == "tum":
        stamp, position, quaternion = values[0], values[1:4], [values[7], *values[4:7]]
    else:
        stamp, position, quaternion = int(fields[0]) / NANOSECONDS if fields[0].isdigit() else values[0] / NANOSECONDS, values[1:4], values[4:8]
    norm = math.sqrt(sum(q * q for q in quaternion))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise DatasetError(
            f"{path}, line {number}: quaternion {quaternion} (w, x, y, z) has norm {norm:.6f}; expected a unit quaternion "
            f"(|norm - 1| <= {UNIT_TOLERANCE}), the rotation of a rigid pose"
        )
    return stamp, position, quaternion


def sample_trajectory(trajectory: Trajectory, stamps: np.ndarray, max_gap: float, what: str = "the images") -> tuple[torch.Tensor, np.ndarray]:
    """The trajectory's poses at ``stamps`` (K,) seconds: a sample within 1 µs is taken as it is,
    otherwise the geodesic between the two samples around the stamp when they lie at most
    ``max_gap`` s apart; elsewhere (outside the file, or across a longer gap in it) no pose.

    Returns:
        poses (K, 4, 4) float64 (identity where there is none) and valid (K,) bool.
    Raises:
        DatasetError: no stamp finds a pose: the file's stamps never overlap ``what``'s, naming both spans.
    """
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    known = trajectory.stamps
    poses = torch.eye(4, dtype=torch.float64).repeat(len(stamps), 1, 1)
    valid = np.zeros(len(stamps), dtype=bool)
    after = np.searchsorted(known, stamps)  # first sample at or after each stamp
    for k, (stamp, j) in enumerate(zip(stamps, after)):
        if j < len(known) and abs(known[j] - stamp) <= 1e-6:
            poses[k], valid[k] = trajectory.poses[j], True
        elif j > 0 and abs(known[j - 1] - stamp) <= 1e-6:
            poses[k], valid[k] = trajectory.poses[j - 1], True
        elif 0 < j < len(known) and known[j] - known[j - 1] <= max_gap:
            fraction = float((stamp - known[j - 1]) / (known[j] - known[j - 1]))
            poses[k], valid[k] = interpolate_pose(trajectory.poses[j - 1], trajectory.poses[j], fraction), True
    if len(stamps) and not valid.any():
        raise DatasetError(
            f"{trajectory.source}: stamps {known[0]:.6f}–{known[-1]:.6f} s (lines {trajectory.lines[0]}–{trajectory.lines[-1]}) never overlap "
            f"{what}' stamps {stamps[0]:.6f}–{stamps[-1]:.6f} s; expected odometry stamped on the images' clock"
        )
    return poses, valid
