"""The surface-distance layer: a float64 brute-force oracle, truncation outside, the map file (round trip, refusals)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from locnerf.errors import MapFileError
from locnerf.field.map_file import load_map, save_map
from locnerf.field.surface_distance import LEVELS, SurfaceDistance, SurfaceDistanceConfig
from tests.field.test_grid_and_map_file import _tiny_map

CONFIG = SurfaceDistanceConfig(voxel=0.05, truncation=0.15, margin=0.2125)
"""The margin, 8.5 half voxels, puts points on multiples of half a voxel at the centres of the merging cells."""


def lattice_points(generator: torch.Generator, count: int = 300) -> torch.Tensor:
    """(count, 3) float64 points on a floor (y = 0) and a wall (x = 1) at multiples of half a voxel: with
    ``CONFIG.margin`` they sit at the centres of the layer's merging cells, so merging moves none."""
    half = CONFIG.voxel / 2
    points = torch.randint(0, 40, (count, 3), generator=generator).double() * half
    points[: count // 2, 1] = 0.0  # the floor
    points[count // 2 :, 0] = 40 * half  # the wall
    return points


def brute_force_distance(queries: torch.Tensor, points: torch.Tensor, truncation: float) -> torch.Tensor:
    """min(‖q − p‖ over the points, truncation) of each query, float64, one at a time."""
    return torch.tensor([min(float((points - q).norm(dim=-1).min()), truncation) for q in queries], dtype=torch.float64)


def test_vertex_distances_match_a_brute_force_oracle_and_lookups_interpolate_them(generator: torch.Generator) -> None:
    """At every vertex the stored distance is the exact truncated distance to the nearest point, to the byte's
    quantisation (truncation / 255 / 2); between vertices the lookup is within half a voxel of the exact distance
    (trilinear interpolation of a distance is not exact); outside the grid it reads the truncation."""
    points = lattice_points(generator)
    layer = SurfaceDistance.from_points(points, CONFIG)
    nx, ny, nz = layer.shape
    vertices = torch.stack(torch.meshgrid(torch.arange(nx), torch.arange(ny), torch.arange(nz), indexing="ij"), dim=-1).reshape(-1, 3)
    chosen = vertices[torch.randperm(len(vertices), generator=generator)[:400]]
    positions = layer.origin.double() + chosen.double() * CONFIG.voxel
    exact = brute_force_distance(positions, points, CONFIG.truncation)
    stored = layer.codes[chosen[:, 2], chosen[:, 1], chosen[:, 0]].double() * CONFIG.truncation / LEVELS
    torch.testing.assert_close(stored, exact, rtol=0, atol=CONFIG.truncation / LEVELS / 2 + 1e-6)
    torch.testing.assert_close(layer(positions), exact, rtol=0, atol=CONFIG.truncation / LEVELS / 2 + 1e-6)
    queries = points[:100] + (torch.rand(100, 3, generator=generator, dtype=torch.float64) - 0.5) * 0.2
    assert (layer(queries) - brute_force_distance(queries, points, CONFIG.truncation)).abs().max() <= CONFIG.voxel / 2
    far = torch.tensor([[50.0, 0.0, 0.0], [0.0, -50.0, 3.0]], dtype=torch.float64)
    torch.testing.assert_close(layer(far), torch.full((2,), CONFIG.truncation, dtype=torch.float64))
    assert layer(queries.reshape(10, 10, 3)).shape == (10, 10)


def test_bad_points_and_records_are_refused(generator: torch.Generator) -> None:
    with pytest.raises(ValueError, match=r"expected \(P, 3\) with P ≥ 1"):
        SurfaceDistance.from_points(torch.zeros(0, 3), CONFIG)
    with pytest.raises(ValueError, match="expected finite coordinates"):
        SurfaceDistance.from_points(torch.tensor([[0.0, math.nan, 0.0]]), CONFIG)
    state = SurfaceDistance.from_points(lattice_points(generator).float(), CONFIG).state()
    assert SurfaceDistance.from_state(state).codes.equal(state["codes"])
    with pytest.raises(MapFileError, match="surface distance layer: 'codes'"):
        SurfaceDistance.from_state({key: value for key, value in state.items() if key != "codes"})
    with pytest.raises(MapFileError, match=r"codes of dtype torch.float32.*expected uint8"):
        SurfaceDistance.from_state(state | {"codes": state["codes"].float()})
    with pytest.raises(MapFileError, match="expected positive finite lengths"):
        SurfaceDistance.from_state(state | {"voxel": -1.0})


def test_a_map_file_keeps_its_layer_and_refuses_a_broken_one(tmp_path: Path, generator: torch.Generator) -> None:
    """Saved and loaded: the same codes and lookups; a map without one loads with None; a layer record that
    is not one is refused naming the file."""
    tiny_grid_map = _tiny_map(generator)
    assert tiny_grid_map.surface_distance is None
    plain = load_map(save_map(tiny_grid_map, tmp_path / "plain.locmap"))
    assert plain.surface_distance is None
    layer = SurfaceDistance.from_points(lattice_points(generator).float(), CONFIG)
    tiny_grid_map.surface_distance = layer
    loaded = load_map(save_map(tiny_grid_map, tmp_path / "layer.locmap")).surface_distance
    assert loaded is not None and loaded.codes.equal(layer.codes) and loaded.voxel == layer.voxel
    queries = torch.rand(50, 3, generator=generator) * 2
    torch.testing.assert_close(loaded(queries), layer(queries))
    tiny_grid_map.surface_distance = SurfaceDistance(layer.origin, layer.voxel, layer.truncation, layer.codes)
    tiny_grid_map.surface_distance.state = lambda: {"origin": layer.origin, "voxel": "wide", "truncation": 0.1, "codes": layer.codes}
    broken = save_map(tiny_grid_map, tmp_path / "broken.locmap")
    with pytest.raises(MapFileError, match=r"broken.locmap: surface distance layer"):
        load_map(broken)
