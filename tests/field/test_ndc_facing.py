"""Rays that look away from a forward-facing (NDC) scene see none of it, on every map backend.

NDC moves a ray onto the plane z = -1 along its own line: a ray with d_z > 0 would be moved
backwards and rendered as its mirror image, and d_z = 0 would give NaN.
"""

from __future__ import annotations

import pytest
import torch

from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.field.grid_map import GridMap
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import NerfMLP, NerfPytorchMap
from locnerf.field.protocol import MapNormalization, RadianceMap
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.ndc import ndc_rays_from_world_rays

INTRINSICS = PinholeIntrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12)
INFO = MapInfo(MapNormalization(ndc=True), INTRINSICS, torch.eye(4, dtype=torch.float64)[None], {"source": "test"})
FACING, AWAY, SIDEWAYS = (-0.1, -0.05, -1.0), (0.1, 0.05, 1.0), (1.0, 0.2, 0.0)


def _grid_map(generator: torch.Generator) -> GridMap:
    """A dense NDC grid map: every ray through the NDC cube meets something."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = GridField(box, GridFieldConfig(voxels=12**3, features=4, render_step_factor=1.0), background=(1.0, 1.0, 1.0))
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator) * 3.0)
        field.grid[:, 0] += 2.0
        for parameter in field.decoder.parameters():  # all drawn here, none from the global generator
            parameter.normal_(generator=generator)
    field.update_occupancy()
    return GridMap(field.eval(), INFO)


def _mlp_map(generator: torch.Generator) -> NerfPytorchMap:
    networks = []
    for _ in range(2):
        network = NerfMLP()
        with torch.no_grad():
            for parameter in network.parameters():
                parameter.copy_(torch.randn(parameter.shape, generator=generator) * 0.1)
            network.alpha_linear.bias.fill_(5.0)  # dense: the facing ray is opaque
        networks.append(network.eval())
    return NerfPytorchMap(networks[0], networks[1], INFO, white_background=True)


@pytest.mark.parametrize("build", [_grid_map, _mlp_map], ids=["grid", "nerf_pytorch"])
def test_rays_looking_away_render_the_background_not_the_mirrored_scene(generator: torch.Generator, build) -> None:
    radiance_map: RadianceMap = build(generator)
    origins = torch.zeros(3, 3)
    directions = torch.tensor([FACING, AWAY, SIDEWAYS])
    rgb = radiance_map.render_rays(origins, directions)
    assert torch.isfinite(rgb).all()
    white = torch.ones(3)
    assert float((rgb[0] - white).abs().max()) > 0.05, "the facing ray must see the (dense) scene"
    torch.testing.assert_close(rgb[1], white)  # was the facing ray's colour: its mirror image
    torch.testing.assert_close(rgb[2], white)  # was NaN
    # Rays that face the scene render as they do alone, wherever they sit in the batch.
    torch.testing.assert_close(radiance_map.render_rays(origins[:1], directions[:1]), rgb[:1])


def test_ndc_warp_refuses_rays_that_look_away() -> None:
    origins = torch.zeros(2, 3, dtype=torch.float64)
    for direction in (AWAY, SIDEWAYS):
        with pytest.raises(ValueError, match="1 of 2 ray directions have d_z >= 0"):
            ndc_rays_from_world_rays(origins, torch.tensor([FACING, direction], dtype=torch.float64), INTRINSICS)
