"""The default map backend: a :class:`GridField` plus its :class:`MapInfo`, as a RadianceMap."""

from __future__ import annotations

from typing import Any

import torch

from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.field.map_info import MapInfo
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
        """Inverse of :meth:`state`, on ``device``."""
        field = GridField(state["box"], GridFieldConfig.model_validate(state["config"]), state["background"])
        field.resize(tuple(state["resolution"]))
        field.load_state_dict(state["weights"])
        return cls(field.to(device).eval(), info)
