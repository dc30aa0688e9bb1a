"""The last published pose and covariance on disk, so that a restarted filter resumes from it."""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from locnerf.geometry.validation import validate_poses

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SavedPose:
    """A metric pose ``T_world_cam`` (4, 4), its 6×6 covariance and the odometry pose
    ``T_odom_body`` (4, 4) of the same stamp (so that a restart applies the motion since), float64.
    Handed to the writer thread: its tensors must not be shared with the filter."""

    stamp: float
    T_world_cam: torch.Tensor
    covariance: torch.Tensor
    T_odom_body: torch.Tensor


def save_pose(path: Path, saved: SavedPose) -> None:
    """Write atomically (write a sibling file, then rename over the old one)."""
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(
        json.dumps(
            {
                "stamp": saved.stamp,
                "T_world_cam": saved.T_world_cam.tolist(),
                "covariance": saved.covariance.tolist(),
                "T_odom_body": saved.T_odom_body.tolist(),
            }
        )
    )
    os.replace(temporary, path)


def load_pose(path: Path) -> SavedPose | None:
    """The saved pose, or None when the file is absent or unreadable (logged)."""
    try:
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
        saved = SavedPose(
            float(data["stamp"]),
            torch.tensor(data["T_world_cam"], dtype=torch.float64),
            torch.tensor(data["covariance"], dtype=torch.float64),
            torch.tensor(data["T_odom_body"], dtype=torch.float64),
        )
        validate_poses(saved.T_world_cam, name=f"{path}: T_world_cam")
        validate_poses(saved.T_odom_body, name=f"{path}: T_odom_body")
        if saved.covariance.shape != (6, 6) or not torch.isfinite(saved.covariance).all():
            raise ValueError(f"covariance: expected a finite 6×6 matrix, got shape {tuple(saved.covariance.shape)}")
    except (ValueError, KeyError, TypeError, OSError) as error:
        logger.warning("ignoring the saved filter state %s: %s", path, error)
        return None
    return saved
