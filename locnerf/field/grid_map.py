"""The default map backend: a :class:`GridField` plus its :class:`MapInfo`, as a RadianceMap."""

from __future__ import annotations

import math
from typing import Any

import torch

from locnerf.errors import MapFileError
from locnerf.field.grid import MAX_GRID_VERTICES, GridField, GridFieldConfig
from locnerf.field.grid_march_fused import compile_ahead
from locnerf.field.map_info import MapInfo
from locnerf.field.map_state import check_state_dict, entry, tensor_of_shape, validated
from locnerf.field.stored_map import StoredMap

GRID_KIND = "grid"


class GridMap(StoredMap):
    """Renders world-frame rays with the grid field (warping them to NDC first for NDC maps)."""

    kind = GRID_KIND

    def __init__(self, field: GridField, info: MapInfo) -> None:
        self.field = field
        self.info = info

    @property
    def samples_per_ray(self) -> int:
        """Samples a ray crossing the whole box would take (an upper bound: empty space is skipped)."""
        extent = (self.field.box[1] - self.field.box[0]).norm()
        return int(extent / (self.field.voxel_size * self.field.config.step_ratio)) + 1

    @property
    def device(self) -> torch.device:
        return self.field.grid.device

    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """rgb (R, 3) in [0, 1] of world-frame rays: origins (R, 3), directions (R, 3) (the background where
        a ray misses the map, including rays looking away from an NDC map's scene)."""
        origins = origins.to(self.device, torch.float32)
        directions = directions.to(self.device, torch.float32)
        return self.info.render_world_rays(origins, directions, self.field.render, self.field.background)

    def render_surface(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """rgb (R, 3), expected surface point (R, 3) and opacity (R,) of world-frame rays (R, 3) x2
        (:meth:`GridField.render_surface`); metric maps only, as the field's space is then the map frame.

        Raises:
            ValueError: for an NDC map, whose field points are not map-frame points.
        """
        if self.info.normalization.ndc:
            raise ValueError("render_surface: the map is an NDC (forward-facing) map, whose field space is not the map frame; expected a metric map")
        origins = origins.to(self.device, torch.float32)
        directions = directions.to(self.device, torch.float32)
        return self.field.render_surface(origins, directions, directions)

    def state(self) -> dict[str, Any]:
        """Weights and shape for the map file."""
        return {
            "config": self.field.config.model_dump(mode="json"),
            "box": self.field.box.detach().cpu().clone(),
            "background": self.field.background.cpu().tolist() if self.field.has_background else None,
            "resolution": list(self.field.resolution),
            "weights": {k: v.detach().cpu().clone() for k, v in self.field.state_dict().items()},
        }

    @classmethod
    def from_state(cls, state: dict[str, Any], info: MapInfo, device: torch.device) -> GridMap:
        """Inverse of :meth:`state`, on ``device``.

        Raises:
            MapFileError: for a state that is not a grid map's (a missing or mistyped entry, a box that
                is not (2, 3) low < high, more than ``MAX_GRID_VERTICES`` vertices, weights whose
                names or shapes differ from the grid's), before the grid is allocated.
        """
        config = validated(GridFieldConfig, entry(state, "config", dict, "grid state"), "grid state: config")
        box = tensor_of_shape(entry(state, "box", torch.Tensor, "grid state"), (2, 3), "grid state: box")
        if not bool((box[1] > box[0]).all()):
            raise MapFileError(f"grid state: box {box.tolist()}, expected low < high on every axis")
        background = entry(state, "background", (list, tuple, type(None)), "grid state")
        if background is not None and (len(background) != 3 or not all(isinstance(c, (int, float)) for c in background)):
            raise MapFileError(f"grid state: background {background!r}, expected None or three numbers")
        resolution = _checked_resolution(entry(state, "resolution", (list, tuple), "grid state"))
        weights = entry(state, "weights", dict, "grid state")
        # The entries the resolution sizes are checked before the grid is allocated, so that a file cannot ask for more than it holds.
        vertices, channels = math.prod(resolution), 4 + config.features
        tensor_of_shape(weights.get("grid"), (vertices, channels), "grid state: weights.grid")
        occupancy = weights.get("occupancy")
        if not isinstance(occupancy, torch.Tensor) or tuple(occupancy.shape) != resolution[::-1]:
            raise MapFileError(f"grid state: weights.occupancy of shape {tuple(getattr(occupancy, 'shape', ()))}, expected {resolution[::-1]} (Rz, Ry, Rx)")
        field = GridField(box, config, None if background is None else tuple(float(c) for c in background), resolution=resolution)
        check_state_dict(weights, field.state_dict(), "grid state: weights")
        field.load_state_dict(weights)
        if device.type == "cpu":
            compile_ahead()
        return cls(field.to(device).eval(), info)


def _checked_resolution(resolution: list | tuple) -> tuple[int, int, int]:
    """(Rx, Ry, Rz) of a stored grid: three integers >= 2 whose product is at most ``MAX_GRID_VERTICES``.

    Raises:
        MapFileError: naming the resolution and the bound it breaks.
    """
    if len(resolution) != 3 or not all(isinstance(r, int) and not isinstance(r, bool) and r >= 2 for r in resolution):
        raise MapFileError(f"grid state: resolution {resolution!r}, expected three integers >= 2 (Rx, Ry, Rz)")
    if math.prod(resolution) > MAX_GRID_VERTICES:
        raise MapFileError(
            f"grid state: resolution {list(resolution)} is {math.prod(resolution)} vertices, more than the {MAX_GRID_VERTICES} a grid map may have"
        )
    return (resolution[0], resolution[1], resolution[2])
