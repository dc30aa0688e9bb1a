"""Similarity transforms (scale, rotation, translation) between point sets and pose sets.

Used to bring a structure-from-motion reconstruction (arbitrary scale and frame) onto a metric
trajectory or a ground truth: ``y ≈ s · R · x + t`` (Umeyama, PAMI 1991, least squares).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Similarity:
    """``y = scale · rotation · x + translation``; ``rotation`` (3, 3), ``translation`` (3,), float64."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def points(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3) transformed points."""
        return self.scale * points @ self.rotation.T + self.translation

    def poses(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Camera-to-world poses (N, 4, 4) -> the same cameras in the target frame (rotation composed, centre transformed)."""
        out = np.array(T_world_cam, dtype=np.float64, copy=True)
        out[:, :3, :3] = self.rotation @ out[:, :3, :3]
        out[:, :3, 3] = self.points(out[:, :3, 3])
        return out


def fit_similarity(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> Similarity:
    """The similarity (or rigid transform, ``with_scale=False``) taking ``source`` (N, 3) closest to ``target`` (N, 3).

    Raises:
        ValueError: for fewer than 3 pairs, shapes that differ, or points that do not span a plane (degenerate fit).
    """
    source, target = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise ValueError(f"similarity fit: expected two (N >= 3, 3) point sets of one shape, got {source.shape} and {target.shape}")
    mean_source, mean_target = source.mean(0), target.mean(0)
    centred_source, centred_target = source - mean_source, target - mean_target
    variance = float((centred_source**2).sum(1).mean())
    covariance = centred_target.T @ centred_source / len(source)
    u, singular, vt = np.linalg.svd(covariance)
    if variance <= 0 or singular[1] <= 1e-12 * max(singular[0], 1e-300):
        raise ValueError(f"similarity fit: the {len(source)} points are (nearly) collinear or coincident; expected points spread in at least a plane")
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign) / variance) if with_scale else 1.0
    return Similarity(scale, rotation, mean_target - scale * rotation @ mean_source)


def fit_similarity_to_poses(source: np.ndarray, target: np.ndarray) -> Similarity:
    """The similarity taking camera-to-world poses ``source`` (N, 4, 4) closest to ``target`` (N, 4, 4): rotation from the
    cameras' orientations (the rotation closest to the mean of ``R_target · R_sourceᵀ``), then scale and translation from the
    centres by least squares.

    A fit on centres alone leaves the rotation about a near-straight or near-planar camera path poorly fixed, which shows as
    the same orientation error on every camera; the orientations fix it.

    Raises:
        ValueError: for fewer than 3 poses, shapes that differ, or coincident centres.
    """
    source, target = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.shape[1:] != (4, 4) or len(source) < 3:
        raise ValueError(f"similarity fit: expected two (N >= 3, 4, 4) pose sets of one shape, got {source.shape} and {target.shape}")
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", target[:, :3, :3], source[:, :3, :3]))
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    centred_source = source[:, :3, 3] - source[:, :3, 3].mean(0)
    centred_target = target[:, :3, 3] - target[:, :3, 3].mean(0)
    variance = float((centred_source**2).sum())
    if variance <= 0:
        raise ValueError(f"similarity fit: the {len(source)} camera centres coincide; expected cameras at different places")
    scale = float(np.einsum("ni,ni->", centred_target, centred_source @ rotation.T) / variance)
    return Similarity(scale, rotation, target[:, :3, 3].mean(0) - scale * rotation @ source[:, :3, 3].mean(0))
