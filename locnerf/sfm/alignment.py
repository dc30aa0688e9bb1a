"""Scoring a map built by structure from motion against a ground truth, and aligning it for evaluation.

One similarity (Umeyama, :func:`locnerf.geometry.similarity.fit_similarity`) is fitted between the
camera centres of the map's own frames (its reference poses) and the ground truth's poses of the
same frames; every registered camera's error is measured after it. The fit also gives a copy of the
map whose normalization carries it (``T_map_dataset``, ``scale``): the evaluation commands, which
take true poses into the map frame through the normalization and estimates out of it, then score an
SfM map in the ground truth's frame with estimates mapped through that one similarity.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.similarity import Similarity, fit_similarity_to_poses

FRAMES_KEY = "frames"
"""Entry of a map's ``sfm`` metadata: the names of its reference poses' frames, in order."""


def frame_key(name: str) -> str:
    """A frame name without its image suffixes: ``seq-01/frame-000000.color`` -> ``seq-01/frame-000000``."""
    return name.split(".")[0]


def alignment_errors(map_poses: np.ndarray, truth_poses: np.ndarray) -> tuple[Similarity, dict[str, Any]]:
    """Fit map -> truth on the cameras (:func:`fit_similarity_to_poses`: rotation from their orientations, scale and
    translation from their centres) and measure each camera after it.

    Args:
        map_poses, truth_poses: (K, 4, 4) float64 camera-to-world poses of the same K frames (one camera-axis convention).
    Returns:
        the similarity and ``translation`` (K,) metres (truth units), ``rotation_deg`` (K,) lists plus a summary.
    """
    similarity = fit_similarity_to_poses(map_poses, truth_poses)
    aligned = similarity.poses(map_poses)
    translation = np.linalg.norm(aligned[:, :3, 3] - truth_poses[:, :3, 3], axis=1)
    relative = np.einsum("kji,kjl->kil", aligned[:, :3, :3], truth_poses[:, :3, :3])
    rotation = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    summary = {
        "frames": len(map_poses),
        "scale_map_to_truth": similarity.scale,
        "translation_median_m": float(np.median(translation)),
        "translation_p90_m": float(np.percentile(translation, 90)),
        "translation_max_m": float(translation.max()),
        "rotation_median_deg": float(np.median(rotation)),
        "rotation_p90_deg": float(np.percentile(rotation, 90)),
        "rotation_max_deg": float(rotation.max()),
        "within_3cm_1deg": float(np.mean((translation <= 0.03) & (rotation <= 1.0))),
    }
    return similarity, {"summary": summary, "translation": translation.tolist(), "rotation_deg": rotation.tolist()}


def aligned_normalization(normalization: MapNormalization, map_to_truth: Similarity, truth: MapNormalization | None = None) -> MapNormalization:
    """``normalization`` whose ``metric_to_map`` takes the ground truth's world poses into the map frame.

    ``map_to_truth`` takes map poses to the ground truth reader's frame, whose own normalization ``truth`` (the
    identity when None: a metric reader such as 7-Scenes') takes its world to that frame. The result is the
    composition ``map_to_truth⁻¹ ∘ truth.metric_to_map``: with ``truth = (A, a)`` (``x ↦ a·A_R x + A_t``) and
    ``map_to_truth = (s, R, t)``, ``scale = a/s`` and ``T_map_dataset = [RᵀA_R | Rᵀ(A_t - t)/s]``. The map's own
    frame (its NDC warp, near, far, up) is kept: only its relation to a data-set world changes.
    """
    truth = truth or MapNormalization()
    A = np.asarray(truth.T_map_dataset, dtype=np.float64)
    transform = np.eye(4)
    transform[:3, :3] = map_to_truth.rotation.T @ A[:3, :3]
    transform[:3, 3] = map_to_truth.rotation.T @ (A[:3, 3] - map_to_truth.translation) / map_to_truth.scale
    return normalization.model_copy(update={"T_map_dataset": transform.tolist(), "scale": truth.scale / map_to_truth.scale})


def truth_of_frames(names: list[str], truth_names: list[str], truth_poses: torch.Tensor) -> tuple[list[int], np.ndarray]:
    """Positions (into ``names``) of the frames the ground truth has, and their true poses (K, 4, 4).

    Raises:
        LocnerfInputError: when fewer than 3 frames are shared (naming examples of both).
    """
    position = {frame_key(name): i for i, name in enumerate(truth_names)}
    shared = [i for i, name in enumerate(names) if frame_key(name) in position]
    if len(shared) < 3:
        raise LocnerfInputError(
            f"map align: {len(shared)} of the map's {len(names)} frames (e.g. {names[:2]}) are in the ground truth read (e.g. {truth_names[:2]}); "
            "expected the data set and split the map was built from"
        )
    return shared, truth_poses[[position[frame_key(names[i])] for i in shared]].double().numpy()
