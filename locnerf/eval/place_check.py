"""How well the keyframe index tells places apart along a sequence: the evidence behind ``recovery.place_check_*``.

The kidnapping detector's place check (:func:`locnerf.filter.recovery.place_recognized`) does not count a low
update whose image the index places near the estimate. It helps when two things hold on the robot's map:

- a tracked filter's images are placed at their own pose (the estimate is there): a dip in the likelihood
  (a dark or blurred stretch) is then not counted, and cannot fire a false detection;
- an image taken far from the estimate is not placed near it: a kidnapping is still detected.

:func:`place_check_report` measures both over a sequence's images with their true poses: the share of
images placed at their own pose, and, over every pair of images whose poses lie at least ``away`` apart,
the share in which one image is placed near the other's pose (a kidnapping between them that the check
would hide at that moment).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from locnerf.filter.keyframes import KeyframeIndex
from locnerf.filter.recovery import recognized_at
from locnerf.geometry.metrics import rotation_error_deg, translation_error


@dataclass(frozen=True)
class PlacedImages:
    """A sequence's images, where they were taken and where the index places them.

    Attributes:
        stamps: (I,) float64 seconds.
        truths: (I, 4, 4) float64 true camera poses, map frame.
        views: (I, V, 4, 4) float64 poses of the V keyframes most like each image, best first.
    """

    stamps: torch.Tensor
    truths: torch.Tensor
    views: torch.Tensor


def place_images(index: KeyframeIndex, images: list[torch.Tensor], stamps: torch.Tensor, truths: torch.Tensor, views: int) -> PlacedImages:
    """Query ``index`` with each image (H, W, 3) in [0, 1] for its ``views`` best keyframes.

    Raises:
        ValueError: the counts of images, stamps (I,) and truths (I, 4, 4) differ, or there are none.
    """
    if not images or len(images) != stamps.shape[0] or truths.shape != (len(images), 4, 4):
        raise ValueError(f"{len(images)} images, stamps {tuple(stamps.shape)}, truths {tuple(truths.shape)}: expected I >= 1 of each")
    placed = torch.stack([index.query(image, views)[0] for image in images])
    return PlacedImages(stamps.double().cpu(), truths.double().cpu(), placed)


def place_check_report(placed: PlacedImages, max_position: float, max_rotation_deg: float, away_position: float, away_rotation_deg: float) -> dict[str, Any]:
    """Both sides of the place check over ``placed`` (see the module's docstring).

    Returns:
        ``images``; ``at_own_place`` (count and share of images placed within the check's reach of their own
        pose) and ``not_at_own_place_s`` (their stamps otherwise); ``away_pairs`` (ordered pairs (i, j) of images
        whose poses differ by at least ``away_position`` and ``away_rotation_deg``) and ``away_pairs_placed_near``
        (count and share of those in which image j is placed near pose i).
    """
    recognized = recognized_at(placed.views, placed.truths, max_position, max_rotation_deg)  # [j, i]
    own = recognized.diagonal()
    truths = placed.truths
    apart = (translation_error(truths[:, None], truths[None]) >= away_position) & (rotation_error_deg(truths[:, None], truths[None]) >= away_rotation_deg)
    pairs = int(apart.sum())
    hidden = int((recognized & apart).sum())
    return {
        "images": len(own),
        "at_own_place": int(own.sum()),
        "share_at_own_place": float(own.double().mean()),
        "not_at_own_place_s": [round(float(s), 3) for s in placed.stamps[~own]],
        "away_pairs": pairs,
        "away_pairs_placed_near": hidden,
        "share_away_placed_near": hidden / pairs if pairs else math.nan,
    }
