"""The place check's evidence (locnerf.eval.place_check) against a naive loop over every pair of images."""

from __future__ import annotations

import math

import torch

from locnerf.eval.place_check import PlacedImages, place_check_report
from locnerf.filter.recovery import place_recognized, recognized_at
from locnerf.geometry import make_pose, se3_exp, so3_exp


def _poses_along_a_line(count: int) -> torch.Tensor:
    """(count, 4, 4) float64 poses 0.25 units apart along x, each turned 12° more about y."""
    return torch.stack(
        [
            make_pose(so3_exp(torch.tensor([0.0, math.radians(12.0 * k), 0.0], dtype=torch.float64)), torch.tensor([0.25 * k, 0.0, 0.0], dtype=torch.float64))
            for k in range(count)
        ]
    )


def test_recognized_at_matches_place_recognized_for_every_pair(generator):
    truths = _poses_along_a_line(9)
    views = truths[torch.randint(0, 9, (9, 3), generator=generator)] @ se3_exp(torch.randn(9, 3, 6, generator=generator, dtype=torch.float64) * 0.15)
    recognized = recognized_at(views, truths, 0.3, 20.0)
    assert recognized.shape == (9, 9)
    for j in range(9):
        for i in range(9):
            assert bool(recognized[j, i]) == place_recognized(views[j], truths[i], 0.3, 20.0)


def test_the_report_counts_own_places_and_far_pairs_as_a_naive_loop_does(generator):
    """Images placed at their own pose except two, one of which is placed at a far image's pose."""
    truths = _poses_along_a_line(10)
    views = (truths @ se3_exp(torch.randn(10, 6, generator=generator, dtype=torch.float64) * 0.01))[:, None].repeat(1, 2, 1, 1)
    views[3] = truths[8]  # image 3 looks like the place of image 8 (1.25 units and 60° away)
    views[5] = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([5.0, 5.0, 5.0], dtype=torch.float64))  # nowhere
    stamps = torch.arange(10, dtype=torch.float64) * 0.2
    report = place_check_report(PlacedImages(stamps, truths, views), 0.1, 5.0, 0.9, 20.0)
    pairs = [(i, j) for i in range(10) for j in range(10) if abs(i - j) >= 4]  # 1.0 units and 48° apart at least
    hidden = sum(place_recognized(views[j], truths[i], 0.1, 5.0) for i, j in pairs)
    assert report["images"] == 10 and report["at_own_place"] == 8 and report["not_at_own_place_s"] == [0.6, 1.0]
    assert report["away_pairs"] == len(pairs) and report["away_pairs_placed_near"] == hidden == 1
    assert report["share_away_placed_near"] == 1 / len(pairs)
