"""The original Loc-NeRF's logged runs (``locnerf_logs`` format), read and scored like ours.

Files are ``<kind>_<scene>_<frame>_<suffix>.npy`` with kinds ``gt`` (4, 4), ``initial_pose``
(6,) = (a, b, c, tx, ty, tz), ``mocnerf`` (K, 4, 4) estimates with ``forward_passes`` (K,),
``mocnerf_started`` (same, without annealing) and ``inerf`` (301, 4, 4). The start pose of a trial
is ``trans(t) · Rz(a) · Ry'(b) · Rx(c) · X_gt`` with ``Ry'(θ) = [[c, 0, -s], [0, 1, 0], [s, 0, c]]``.

Two facts of the logs are handled here, not left to the scoring:

- every ``inerf`` file's last slot (index 300) is all zeros: the original preallocated 301 slots
  and filled 300 (the start and 299 iterations). A zero matrix is no pose (its "rotation error" is
  0° to any truth), so trailing all-zero slots are dropped; a zero slot before a filled one is
  refused as corruption.
- the ``inerf`` runs log no forward passes; iNeRF spent ``INERF_RAYS_PER_ITERATION`` rays ×
  ``ORIGINAL_SAMPLES_PER_RAY`` samples per iteration (``../shared/data/README.md``), so the
  estimate in slot ``k`` cost ``k`` times that.

Both methods of the original counted a forward pass as one ray × 128 samples (64 coarse + 64
fine), so a logged run's rays are its forward passes ÷ 128: the budget that compares with ours,
whose backends take other numbers of samples per ray.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from locnerf.errors import DatasetError
from locnerf.geometry import make_pose, rotation_error_deg, translation_error
from locnerf.geometry.validation import validate_poses

_GT_NAME = re.compile(r"^gt_(?P<scene>.+)_(?P<frame>\d+)_poses\.npy$")

INERF_RAYS_PER_ITERATION = 2048
ORIGINAL_SAMPLES_PER_RAY = 128  # 64 coarse + 64 fine: the original's forward passes per ray


@dataclass(frozen=True)
class LoggedRun:
    """One logged estimator run: estimates (K, 4, 4) float64 and cumulative forward passes (K,)."""

    poses: torch.Tensor
    forward_passes: torch.Tensor | None

    def errors(self, truth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Translation (K,) and rotation (K,) degree errors of every estimate against ``truth``."""
        expanded = truth.expand_as(self.poses)
        return translation_error(self.poses, expanded), rotation_error_deg(self.poses, expanded)

    @property
    def rays(self) -> torch.Tensor | None:
        """(K,) cumulative rays rendered: forward passes ÷ ``ORIGINAL_SAMPLES_PER_RAY``."""
        return None if self.forward_passes is None else self.forward_passes // ORIGINAL_SAMPLES_PER_RAY


@dataclass(frozen=True)
class LoggedTrial:
    """The logged inputs and outputs of one original trial."""

    scene: str
    frame: int
    truth: torch.Tensor
    perturbation: torch.Tensor
    locnerf: LoggedRun | None
    locnerf_no_annealing: LoggedRun | None
    inerf: LoggedRun | None

    @property
    def translation_offset(self) -> torch.Tensor:
        """(3,) the logged translation offset (tx, ty, tz) in scene units."""
        return self.perturbation[3:]

    def start_pose(self) -> torch.Tensor:
        """The iNeRF protocol's start ``trans(t) · Rz(a) · Ry'(b) · Rx(c) · X_gt`` (4, 4)."""
        a, b, c = (float(v) for v in self.perturbation[:3])
        rz = torch.tensor([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]], dtype=torch.float64)
        ry = torch.tensor([[np.cos(b), 0, -np.sin(b)], [0, 1, 0], [np.sin(b), 0, np.cos(b)]], dtype=torch.float64)
        rx = torch.tensor([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]], dtype=torch.float64)
        rotate = make_pose(rz @ ry @ rx, torch.zeros(3, dtype=torch.float64))
        shift = make_pose(torch.eye(3, dtype=torch.float64), self.translation_offset)
        return shift @ rotate @ self.truth


def _load(path: Path, shape_tail: tuple[int, ...]) -> torch.Tensor:
    array = np.load(path)
    if tuple(array.shape[len(array.shape) - len(shape_tail) :]) != shape_tail:
        raise DatasetError(f"{path}: expected shape (..., {', '.join(map(str, shape_tail))}), got {array.shape}")
    if not np.isfinite(array).all():
        raise DatasetError(f"{path}: contains NaN or inf")
    return torch.from_numpy(array.astype(np.float64))


def _filled_slots(poses: torch.Tensor, path: Path) -> int:
    """Number of leading filled (not all-zero) slots of ``poses`` (K, 4, 4).

    Raises:
        DatasetError: if an all-zero slot comes before a filled one, or no slot is filled.
    """
    empty = (poses == 0).flatten(1).all(dim=1)
    filled = int((~empty).nonzero().max()) + 1 if (~empty).any() else 0
    if filled == 0 or empty[:filled].any():
        first = int(empty.nonzero()[0])
        raise DatasetError(f"{path}: slot {first} of {len(poses)} is an all-zero matrix before filled ones; expected estimates, then only unfilled slots")
    return filled


def _run(folder: Path, prefix: str, passes_per_slot: int | None = None) -> LoggedRun | None:
    """The run ``<prefix>_poses.npy`` with its forward passes (from ``<prefix>_forward_passes.npy``,
    else ``slot × passes_per_slot`` when given); trailing unfilled slots dropped."""
    poses_path = folder / f"{prefix}_poses.npy"
    if not poses_path.exists():
        return None
    poses = _load(poses_path, (4, 4))
    filled = _filled_slots(poses, poses_path)
    passes_path = folder / f"{prefix}_forward_passes.npy"
    if passes_path.exists():
        passes = torch.from_numpy(np.load(passes_path).astype(np.int64))
        if passes.shape != (len(poses),):
            raise DatasetError(f"{passes_path}: expected shape ({len(poses)},) to match {poses_path.name}, got {tuple(passes.shape)}")
        passes = passes[:filled]
    elif passes_per_slot is not None:
        passes = torch.arange(filled, dtype=torch.int64) * passes_per_slot
    else:
        passes = None
    return LoggedRun(poses[:filled], passes)


def read_logged_trials(folder: str | Path, scene: str | None = None) -> list[LoggedTrial]:
    """Every trial in a log folder (optionally of one scene), sorted by frame.

    Raises:
        FileNotFoundError: if the folder does not exist or holds no ``gt_*_poses.npy`` file.
        DatasetError: if a file has the wrong shape or non-finite values.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: log folder not found")
    trials = []
    for path in sorted(folder.glob("gt_*_poses.npy")):
        match = _GT_NAME.match(path.name)
        if match is None or (scene is not None and match["scene"] != scene):
            continue
        name, frame = match["scene"], int(match["frame"])
        stem = f"{name}_{frame}"
        truth = _load(path, (4, 4))
        validate_poses(truth, name=str(path))
        perturbation_path = folder / f"initial_pose_{stem}_poses.npy"
        if not perturbation_path.exists():
            raise FileNotFoundError(f"{perturbation_path}: the start of logged trial {stem} is missing")
        perturbation = _load(perturbation_path, (6,))
        trials.append(
            LoggedTrial(
                name,
                frame,
                truth,
                perturbation,
                _run(folder, f"mocnerf_{stem}"),
                _run(folder, f"mocnerf_started_{stem}"),
                _run(folder, f"inerf_{stem}", passes_per_slot=INERF_RAYS_PER_ITERATION * ORIGINAL_SAMPLES_PER_RAY),
            )
        )
    if not trials:
        raise FileNotFoundError(f"{folder}: no logged trials (gt_<scene>_<frame>_poses.npy) found" + (f" for scene {scene!r}" if scene else ""))
    return sorted(trials, key=lambda t: (t.scene, t.frame))
