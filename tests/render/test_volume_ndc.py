"""Volume-rendering pieces and the NDC warp, against hand-worked values and naive oracles."""

from __future__ import annotations

import math

import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.ndc import ndc_rays_from_world_rays
from locnerf.render.volume import ray_box_intersection, weights_from_optical_depth


def test_weights_hand_worked() -> None:
    depth = torch.tensor([[0.0, math.log(2.0), math.log(2.0), 1e9]], dtype=torch.float64)
    weights, transmittance = weights_from_optical_depth(depth)
    # alphas 0, 1/2, 1/2, 1: weights 0, 1/2, 1/4, 1/4; nothing left after.
    torch.testing.assert_close(weights, torch.tensor([[0.0, 0.5, 0.25, 0.25]], dtype=torch.float64))
    assert float(transmittance) == 0.0


def test_weights_match_naive_loop(generator: torch.Generator) -> None:
    depth = torch.rand(5, 9, generator=generator, dtype=torch.float64)
    weights, transmittance = weights_from_optical_depth(depth)
    for ray in range(5):
        survive = 1.0
        for k in range(9):
            alpha = 1.0 - math.exp(-float(depth[ray, k]))
            assert abs(float(weights[ray, k]) - survive * alpha) < 1e-12
            survive *= 1.0 - alpha
        assert abs(float(transmittance[ray]) - survive) < 1e-12


def test_ray_box_intersection() -> None:
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    origins = torch.tensor([[-3.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-3.0, 5.0, 0.0]])
    directions = torch.tensor([[2.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    entry, exit_ = ray_box_intersection(origins, directions, box)
    torch.testing.assert_close(entry[:2], torch.tensor([1.0, 0.0]))
    torch.testing.assert_close(exit_[:2], torch.tensor([2.0, 1.0]))
    assert exit_[2] <= entry[2]


def test_ndc_points_are_projections_of_world_points(generator: torch.Generator) -> None:
    intrinsics = PinholeIntrinsics(fx=400.0, fy=410.0, cx=250.0, cy=190.0, width=500, height=380)
    origins = torch.randn(16, 3, generator=generator, dtype=torch.float64) * 0.2
    directions = torch.cat((torch.randn(16, 2, generator=generator, dtype=torch.float64) * 0.3, -torch.ones(16, 1, dtype=torch.float64)), dim=1)
    ndc_o, ndc_d = ndc_rays_from_world_rays(origins, directions, intrinsics, near_plane=1.0)
    torch.testing.assert_close(ndc_o[:, 2], -torch.ones(16, dtype=torch.float64))
    # The world point at depth z on the ray maps to NDC (ax x/z, ay y/z, 1 + 2/z), on the NDC ray.
    for depth in (1.5, 3.0, 40.0):
        s = (-depth - origins[:, 2]) / directions[:, 2]
        world = origins + s[:, None] * directions
        expected = torch.stack((-2 * 400.0 / 500 * world[:, 0] / world[:, 2], -2 * 410.0 / 380 * world[:, 1] / world[:, 2], 1 + 2.0 / world[:, 2]), dim=1)
        t = (expected[:, 2] - ndc_o[:, 2]) / ndc_d[:, 2]
        torch.testing.assert_close(ndc_o + t[:, None] * ndc_d, expected, atol=1e-9, rtol=0)
