"""Metric scale and gravity for a structure-from-motion frame, and the record of how they were obtained.

An SfM reconstruction has no scale and no up direction. Scale sources (metres per SfM unit):

- ``depth``: sensor depth images against the depth of the SfM points each image sees (per image the
  median ratio, then the median over images);
- ``trajectory``: a similarity fit of the SfM camera centres to a metric odometry/VIO trajectory
  recorded with the capture, matched by time stamp (which also gives gravity: the trajectory frame's +z);
- ``user``: ``--scale`` directly, or ``--known-distance A B METRES`` between two frames' camera centres.

Gravity: ``--up`` (a direction in the first image's camera frame, OpenCV axes: x right, y down, z
forward; a level camera has up = 0 -1 0), the trajectory's +z, or, without either, the direction
perpendicular to every camera's x axis (``level_cameras``: cameras held without roll, as hand-held and
robot cameras are, have horizontal x axes whatever their pitch; OpenSfM's upright prior); when the cameras
barely turn (their x axes all about parallel) the mean of their up axes in the plane perpendicular to
the common x axis (``camera_mean``, which assumes level pitch too).

Sources that disagree by more than ``SCALE_TOLERANCE`` are refused; depth ratios of single images that
disagree with the median by more than it are named in a warning, and refused when they are many
(the reconstruction's scale drifts along the capture).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from locnerf.data.trajectory_files import Trajectory, sample_trajectory
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.geometry.similarity import Similarity, fit_similarity

logger = logging.getLogger(__name__)

SCALE_TOLERANCE = 0.05
"""Largest relative disagreement between scale sources, or of one image's depth ratio with the median."""
DRIFT_FRACTION = 0.2
"""Depth scale: more than this fraction of images off the median by SCALE_TOLERANCE is a drifting reconstruction (refused)."""
MIN_DEPTH_PAIRS = 20
"""Fewest SfM points with a sensor reading for an image's depth ratio."""
MAX_TRAJECTORY_GAP = 0.2
"""Largest gap (s) between two trajectory poses across which an image's position is interpolated."""


@dataclass(frozen=True)
class ScaleEstimate:
    """Metres per SfM unit and where it came from (``detail``: figures recorded in the map)."""

    value: float
    source: str
    detail: dict[str, Any] = field(default_factory=dict)


def scale_from_depth(ratios: dict[str, float]) -> ScaleEstimate:
    """The median of per-image depth ratios (sensor depth / SfM depth), checked for drift.

    Args:
        ratios: image name -> its median ratio over the SfM points it sees.
    Raises:
        DatasetError: no image has a ratio, or more than DRIFT_FRACTION of them disagree with the median
            by more than SCALE_TOLERANCE (naming them).
    """
    if not ratios:
        raise DatasetError(
            f"depth scale: no image has {MIN_DEPTH_PAIRS} SfM points with a valid sensor depth; check that the depth images belong to the colour images"
        )
    values = np.array(list(ratios.values()))
    scale = float(np.median(values))
    off = {name: round(value / scale - 1.0, 4) for name, value in ratios.items() if abs(value / scale - 1.0) > SCALE_TOLERANCE}
    listing = ", ".join(f"{name} ({100 * rel:+.1f} %)" for name, rel in list(off.items())[:15]) + (" ..." if len(off) > 15 else "")
    if len(off) > DRIFT_FRACTION * len(ratios):
        raise DatasetError(
            f"depth scale: {len(off)} of {len(ratios)} images disagree with the median scale {scale:.4f} by more than {100 * SCALE_TOLERANCE:.0f} %: "
            f"{listing}; the reconstruction's scale drifts (or the depth images are not these images'); capture with more overlap or give --scale"
        )
    if off:
        logger.warning(
            "depth scale: %d of %d images disagree with the median %.4f by more than %.0f %%: %s", len(off), len(ratios), scale, 100 * SCALE_TOLERANCE, listing
        )
    spread = np.percentile(values / scale, [25, 75])
    return ScaleEstimate(scale, "depth", {"images": len(ratios), "quartiles_relative": [round(float(q), 4) for q in spread], "images_off": sorted(off)})


def depth_ratios(observations: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Per image, the median of sensor depth / SfM depth over its points with both (at least MIN_DEPTH_PAIRS).

    Args:
        observations: image name -> (SfM depths (P,), sensor depths (P,)), 0 where the sensor has none.
    """
    ratios = {}
    for name, (sfm, sensor) in observations.items():
        valid = (sensor > 0) & (sfm > 0)
        if valid.sum() >= MIN_DEPTH_PAIRS:
            ratios[name] = float(np.median(sensor[valid] / sfm[valid]))
    return ratios


def scale_from_known_distance(centres: dict[str, np.ndarray], first: str, second: str, metres: float) -> ScaleEstimate:
    """Metres per SfM unit from the distance between two frames' camera centres.

    Raises:
        LocnerfInputError: a frame that has no pose (naming the posed ones), coincident centres, or a distance <= 0.
    """
    if metres <= 0:
        raise LocnerfInputError(f"--known-distance {first} {second} {metres}: expected a distance > 0 metres")
    for name in (first, second):
        if name not in centres:
            close = [c for c in centres if name in c][:5]
            raise LocnerfInputError(f"--known-distance: frame {name!r} has no pose in the reconstruction; posed frames include {close or list(centres)[:5]}")
    units = float(np.linalg.norm(centres[first] - centres[second]))
    if units <= 1e-9:
        raise LocnerfInputError(f"--known-distance: frames {first} and {second} have the same camera centre; name two frames apart")
    return ScaleEstimate(metres / units, "known_distance", {"frames": [first, second], "metres": metres, "sfm_units": round(units, 6)})


def fit_to_trajectory(centres: np.ndarray, stamps: np.ndarray, trajectory: Trajectory) -> tuple[Similarity, dict]:
    """The similarity taking SfM camera centres (N, 3) at ``stamps`` (N,) onto a metric trajectory's positions.

    Each image is paired with the trajectory pose at its stamp (:func:`sample_trajectory`, interpolated
    across gaps of at most MAX_TRAJECTORY_GAP s); the body-to-camera offset is neglected (centimetres
    against a capture of metres).

    Raises:
        DatasetError: fewer than 3 images pair with the trajectory (naming the stamp ranges).
    """
    poses, valid = sample_trajectory(trajectory, stamps, MAX_TRAJECTORY_GAP, "the capture's images")
    if valid.sum() < 3:
        raise DatasetError(f"trajectory {trajectory.source}: {int(valid.sum())} image stamps fall in it; expected at least 3 images on the trajectory's clock")
    target = poses[valid, :3, 3].numpy()
    try:
        similarity = fit_similarity(centres[valid], target)
    except ValueError as error:
        raise DatasetError(f"trajectory {trajectory.source}: {error}") from error
    residual = np.linalg.norm(similarity.points(centres[valid]) - target, axis=1)
    return similarity, {
        "file": trajectory.source,
        "images": int(valid.sum()),
        "residual_median_m": round(float(np.median(residual)), 4),
        "residual_max_m": round(float(residual.max()), 4),
    }


def agreed_scale(estimates: list[ScaleEstimate]) -> ScaleEstimate | None:
    """The first estimate (user, then trajectory, then depth, as ordered by the caller), checked against the others.

    Raises:
        LocnerfInputError: two estimates that differ by more than SCALE_TOLERANCE (naming both).
    """
    if not estimates:
        return None
    chosen = estimates[0]
    for other in estimates[1:]:
        if abs(other.value / chosen.value - 1.0) > SCALE_TOLERANCE:
            raise LocnerfInputError(
                f"scale sources disagree: {chosen.source} gives {chosen.value:.5f} m per SfM unit, {other.source} {other.value:.5f} "
                f"({100 * (other.value / chosen.value - 1.0):+.1f} %, more than {100 * SCALE_TOLERANCE:.0f} %); check the distance, the depth images or "
                "the trajectory, or give only the source you trust"
            )
    return chosen


MIN_TURN = 0.01
"""Least second eigenvalue of the mean outer product of the cameras' x axes (about a 6° spread of headings)
for the level-camera up axis; below it the headings do not fix it."""


def level_camera_up(T_world_cam_cv: np.ndarray) -> tuple[np.ndarray, str]:
    """(3,) unit up direction of cameras held without roll, and its source (``level_cameras`` | ``camera_mean``).

    The unit vector least aligned with every camera's x axis (the smallest eigenvector of their mean outer product),
    signed to agree with the cameras' up axes (-y, OpenCV axes); when the x axes span no plane (cameras that do not
    turn), the cameras' mean up axis with its component along the common x axis removed.

    Args:
        T_world_cam_cv: (N, 4, 4) camera-to-world poses, OpenCV axes.
    """
    x_axes = T_world_cam_cv[:, :3, 0]
    values, vectors = np.linalg.eigh(x_axes.T @ x_axes / len(x_axes))
    mean_up = mean_camera_up(T_world_cam_cv)
    if values[1] >= MIN_TURN:
        up = vectors[:, 0]
        return up * np.sign(up @ mean_up or 1.0), "level_cameras"
    common = vectors[:, 2]
    up = mean_up - (mean_up @ common) * common
    return up / max(np.linalg.norm(up), 1e-12), "camera_mean"


def mean_camera_up(T_world_cam_cv: np.ndarray) -> np.ndarray:
    """(3,) unit mean of the cameras' up axes (-y of OpenCV camera axes) in the world frame of poses (N, 4, 4)."""
    up = -T_world_cam_cv[:, :3, 1].mean(0)
    norm = np.linalg.norm(up)
    if norm < 0.3:
        logger.warning("gravity: the cameras' up axes point every way (mean length %.2f); the map's up axis is a guess: give --up", norm)
    return up / max(norm, 1e-12)


def rotation_to_z_up(up: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking the unit vector ``up`` onto +z."""
    up = up / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    sine, cosine = np.linalg.norm(axis), float(up @ z)
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / sine
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    angle = np.arctan2(sine, cosine)
    return np.eye(3) + np.sin(angle) * skew + (1 - np.cos(angle)) * skew @ skew
