"""The radiance-field protocol: what the localizer and the services need of a map.

Every map backend (the grid field, the nerf-pytorch MLP, and the analytic procedural world of
:mod:`locnerf.sim`) satisfies :class:`RadianceMap`. The filter reaches it only through the
``render_rays`` callable that the measurement model receives.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.render.camera import PinholeIntrinsics


class MapNormalization(BaseModel):
    """How a map's (NeRF) frame relates to the data set's metric world frame."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    T_map_dataset: list[list[float]] = Field(
        default_factory=lambda: [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
        description="4×4 rigid transform (rotation + translation, in map units) taking data-set world "
        "coordinates, after scaling by `scale`, into the map frame.",
    )
    scale: float = Field(1.0, gt=0, description="Map units per metre of the data set's world frame.")
    ndc: bool = Field(False, description="Rays are warped to normalised device coordinates (forward-facing LLFF).")
    near: float = Field(0.0, ge=0, description="Near bound of rays in map units (before any NDC warp).")
    far: float = Field(1e3, gt=0, description="Far bound of rays in map units (before any NDC warp).")
    up: tuple[float, float, float] = Field(
        (0.0, 1.0, 0.0), description="Unit axis of the map frame opposite to gravity (the yaw axis of global localization)."
    )


@runtime_checkable
class RadianceMap(Protocol):
    """A map that renders colours along arbitrary rays in its own (map) frame."""

    @property
    def samples_per_ray(self) -> int:
        """Field evaluations per ray, for counting forward passes (rays × samples)."""

    @property
    def device(self) -> torch.device:
        """Where ``render_rays`` computes."""

    @property
    def normalization(self) -> MapNormalization:
        """The map frame's relation to the metric data-set frame."""

    @property
    def default_intrinsics(self) -> PinholeIntrinsics:
        """The camera the map was built for (used when a request names none)."""

    def camera_bounds(self) -> torch.Tensor:
        """(2, 3) min and max corner of the region where camera positions are plausible (map frame)."""

    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Colours of rays: origins (R, 3), directions (R, 3), map frame -> rgb (R, 3) in [0, 1]."""
