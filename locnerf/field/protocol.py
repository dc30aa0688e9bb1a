"""The radiance-field protocol: what the localizer and the services need of a map.

Every map backend (the grid field, the nerf-pytorch MLP, and the analytic procedural world of
:mod:`locnerf.sim`) satisfies :class:`RadianceMap`. The filter reaches it only through the
``render_rays`` callable that the measurement model receives.

:class:`MapNormalization` also converts between the data set's metric world frame and the map
frame (design section 5): ``T_map_cam = T_map_dataset · scaled(T_world_cam)``, where ``scaled``
multiplies the translation by the map's scale (map units per metre). Covariances are in the
tangent space at the pose, on the right (``pose · Exp(δ)``, rotation first), so only their
translation block changes, by the scale squared.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.se3 import pose_inverse
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import SurfaceDistanceLookup, SurfaceRays


def _translation_scaled(poses: torch.Tensor, factor: float) -> torch.Tensor:
    """Copies of poses (..., 4, 4) with the translation multiplied by ``factor``."""
    out = poses.clone()
    out[..., :3, 3] = out[..., :3, 3] * factor
    return out


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
    up: tuple[float, float, float] = Field((0.0, 1.0, 0.0), description="Unit axis of the map frame opposite to gravity (the yaw axis of global localization).")

    def _T_map_dataset(self, like: torch.Tensor) -> torch.Tensor:
        """``T_map_dataset`` (4, 4) in the dtype and on the device of ``like``."""
        return torch.tensor(self.T_map_dataset, dtype=like.dtype, device=like.device)

    def metric_to_map(self, T_world_cam: torch.Tensor) -> torch.Tensor:
        """Poses (..., 4, 4) in the metric world frame -> map-frame poses ``T_map_cam`` (..., 4, 4), map units."""
        return self._T_map_dataset(T_world_cam) @ _translation_scaled(T_world_cam, self.scale)

    def map_to_metric(self, T_map_cam: torch.Tensor) -> torch.Tensor:
        """Map-frame poses (..., 4, 4) -> metric world-frame poses (..., 4, 4); the inverse of :meth:`metric_to_map`."""
        return _translation_scaled(pose_inverse(self._T_map_dataset(T_map_cam)) @ T_map_cam, 1.0 / self.scale)

    def increment_to_map(self, T_prev_curr: torch.Tensor) -> torch.Tensor:
        """Body-frame motion increments (..., 4, 4) in metres -> map units (rotation unchanged)."""
        return _translation_scaled(T_prev_curr, self.scale)

    def _covariance_scaled(self, covariance: torch.Tensor, factor: float) -> torch.Tensor:
        """``D Σ D`` float64 (6, 6) with ``D = diag(1, 1, 1, factor, factor, factor)``."""
        if covariance.shape != (6, 6):
            raise ValueError(f"covariance: expected shape (6, 6) (rotation, translation), got {tuple(covariance.shape)}")
        d = torch.tensor([1.0, 1.0, 1.0, factor, factor, factor], dtype=torch.float64, device=covariance.device)
        return covariance.double() * d[:, None] * d[None, :]

    def covariance_to_map(self, covariance: torch.Tensor) -> torch.Tensor:
        """A (rotation, translation) tangent covariance (6, 6) in metres -> map units, float64 (6, 6)."""
        return self._covariance_scaled(covariance, self.scale)

    def covariance_to_metric(self, covariance: torch.Tensor) -> torch.Tensor:
        """A (rotation, translation) tangent covariance (6, 6) in map units -> metres, float64 (6, 6)."""
        return self._covariance_scaled(covariance, 1.0 / self.scale)


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

    @property
    def checksum(self) -> str | None:
        """Identity of the map's content, the same for the same content (SHA-256 hex: of a map file's payload, of the
        procedural world's configuration); None for a map built in memory and not saved."""

    def camera_bounds(self) -> torch.Tensor:
        """(2, 3) min and max corner of the region where camera positions are plausible (map frame)."""

    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Colours of rays: origins (R, 3), directions (R, 3), map frame -> rgb (R, 3) in [0, 1]."""


def surface_renderer(radiance_map: RadianceMap) -> SurfaceRays | None:
    """The map's ``render_surface`` when it can place what it renders in the map frame (grid maps
    that are not NDC, the procedural world); None for the others (NDC maps, the nerf-pytorch MLP)."""
    render_surface = getattr(radiance_map, "render_surface", None)
    if render_surface is None or radiance_map.normalization.ndc:
        return None
    return render_surface


def surface_distance_of(radiance_map: RadianceMap) -> SurfaceDistanceLookup | None:
    """The map's surface-distance lookup, points (..., 3) -> distances (...) in map units
    (:class:`locnerf.field.surface_distance.SurfaceDistance`), when it has one (maps built from depth images); else None."""
    return getattr(radiance_map, "surface_distance", None)
