"""A map's surface-distance layer: the distance from any point to the nearest surface the depth camera measured.

RGB-D maps (7-Scenes; a RealSense robot) are built from depth images as well as colour. Their
back-projected points say where the surfaces are, at the sensor's own resolution and without the
grid's 5.6 cm voxels, total variation or free-space trade-offs. This layer keeps that geometry as a
**truncated unsigned distance grid**: at every vertex of a regular grid (``voxel`` apart, over the
points' box), ``min(distance to the nearest point, truncation)``, quantised to a byte (``truncation /
255`` steps: 0.24 mm at 6 cm). A lookup is trilinear between the eight vertices around a point;
outside the grid it is ``truncation``.

The RGB-D likelihood then needs no rendering at all: a depth pixel of the observed image, moved into
the world by a particle's depth-camera pose, is as far from the map's surface as the lookup says
(:func:`locnerf.filter.depth_measurement.surface_distance_log_likelihoods`), the likelihood-field model
of 2-D laser localization (nav2_amcl's ``likelihood_field``) in 3-D. That is exact where the surface
was measured, costs one lookup per pixel and particle, and is what relocalizes the kitchen's frames
880–915, where the grid's rendered surface lies 4–7 cm from the recorded poses (docs/RESULTS.md).

Building (:meth:`SurfaceDistance.from_points`): points are first merged on a lattice of half a voxel
(one point per occupied cell, at the cell's centre: at most a quarter voxel off), then every grid vertex
within ``truncation`` of a point takes the distance to it, the smallest one winning (a scatter-min over
the vertex offsets from each point's nearest vertex within ``truncation / voxel + √3/2`` voxels): exact
for the merged points up to the truncation.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import MapFileError

logger = logging.getLogger(__name__)

LEVELS = 255
"""Quantisation levels of a stored distance (uint8): 0 = on a point, 255 = the truncation or farther."""


class SurfaceDistanceConfig(BaseModel):
    """How fine a surface-distance layer is, in map units."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    voxel: float = Field(0.02, gt=0, description="Vertex spacing of the distance grid (redkitchen: 278×158×153 vertices at 2 cm, 6.7 MB).")
    truncation: float = Field(0.06, gt=0, description="Largest stored distance: farther points read this (the likelihood truncates at or below it).")
    margin: float = Field(0.1, ge=0, description="The grid spans the points' box grown by this on every side.")


class SurfaceDistance:
    """A truncated distance grid; call it with points (..., 3) to get distances (...).

    Attributes:
        origin: (3,) float32 map-frame position of vertex (0, 0, 0).
        voxel: vertex spacing, map units.
        truncation: the largest distance stored.
        codes: (Nz, Ny, Nx) uint8, ``round(255 · min(d, truncation) / truncation)``.
    """

    def __init__(self, origin: torch.Tensor, voxel: float, truncation: float, codes: torch.Tensor) -> None:
        if codes.dtype != torch.uint8 or codes.ndim != 3 or min(codes.shape) < 2:
            raise ValueError(f"surface distance codes of dtype {codes.dtype}, shape {tuple(codes.shape)}: expected uint8 (Nz, Ny, Nx), each ≥ 2")
        if tuple(origin.shape) != (3,) or not bool(torch.isfinite(origin).all()):
            raise ValueError(f"surface distance origin {origin.tolist()}: expected 3 finite coordinates")
        if not (math.isfinite(voxel) and voxel > 0 and math.isfinite(truncation) and truncation > 0):
            raise ValueError(f"surface distance voxel {voxel}, truncation {truncation}: expected positive finite lengths")
        self.origin = origin.float()
        self.voxel = float(voxel)
        self.truncation = float(truncation)
        self.codes = codes
        self._volume = (codes.float() * (self.truncation / LEVELS))[None, None]
        nz, ny, nx = codes.shape
        self._extent = torch.tensor([nx - 1, ny - 1, nz - 1], dtype=torch.float32, device=codes.device) * self.voxel

    @property
    def shape(self) -> tuple[int, int, int]:
        """(Nx, Ny, Nz) vertices per axis."""
        nz, ny, nx = self.codes.shape
        return nx, ny, nz

    def to(self, device: torch.device | str) -> SurfaceDistance:
        """The same layer with its grid on ``device``."""
        return SurfaceDistance(self.origin.to(device), self.voxel, self.truncation, self.codes.to(device))

    @classmethod
    @torch.no_grad()
    def from_points(cls, points: torch.Tensor, config: SurfaceDistanceConfig) -> SurfaceDistance:
        """The layer of surface points (P, 3) in map units (e.g. every valid depth pixel of the training frames).

        Raises:
            ValueError: for no points or non-finite ones.
        """
        if points.ndim != 2 or points.shape[-1] != 3 or len(points) == 0:
            raise ValueError(f"surface points of shape {tuple(points.shape)}: expected (P, 3) with P ≥ 1")
        if not bool(torch.isfinite(points).all()):
            raise ValueError("surface points: expected finite coordinates, got NaN or infinity")
        started = time.monotonic()
        points = points.double()
        voxel, truncation = config.voxel, config.truncation
        origin = points.amin(dim=0) - config.margin
        shape = ((points.amax(dim=0) + config.margin - origin) / voxel).ceil().long() + 1
        merged = torch.unique(((points - origin) / (voxel / 2)).floor().long(), dim=0)
        points = ((merged.double() + 0.5) * (voxel / 2)).float()  # relative to origin
        nearest = (points / voxel).round().long()
        nx, ny, nz = shape.tolist()
        reach = math.ceil(truncation / voxel)
        span = torch.arange(-reach, reach + 1)
        offsets = torch.cartesian_prod(span, span, span)
        # a vertex farther than the truncation from its point's nearest vertex (plus that vertex's own
        # half-diagonal) stores the truncation anyway: those offsets are skipped
        offsets = offsets[offsets.double().norm(dim=-1) <= truncation / voxel + math.sqrt(3) / 2]
        # a grid padded by ``reach`` vertices on every side takes every offset without a bounds test
        px, py, pz = nx + 2 * reach, ny + 2 * reach, nz + 2 * reach
        distances = torch.full((px * py * pz,), truncation, dtype=torch.float32)
        padded = nearest + reach
        base = ((padded[:, 2] * py + padded[:, 1]) * px + padded[:, 0]).int()
        from_nearest = nearest.float() * voxel - points  # (P, 3) from each point to its nearest vertex
        for offset in offsets:
            distance = (from_nearest + offset.float() * voxel).norm(dim=-1)
            distances.scatter_reduce_(0, (base + int((offset[2] * py + offset[1]) * px + offset[0])).long(), distance, "amin")
        inner = distances.reshape(pz, py, px)[reach : reach + nz, reach : reach + ny, reach : reach + nx]
        codes = (inner.clamp_max(truncation) * (LEVELS / truncation)).round().to(torch.uint8).contiguous()
        logger.info(
            "surface distance: %d×%d×%d vertices at %.3f from %d merged points (%d offsets) in %.1f s",
            nx,
            ny,
            nz,
            voxel,
            len(points),
            len(offsets),
            time.monotonic() - started,
        )
        return cls(origin.float(), voxel, truncation, codes)

    @torch.no_grad()
    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """Distances (...) to the nearest surface of map-frame points (..., 3), trilinear, ``truncation`` outside the grid."""
        return self.lookup(points)

    def lookup(self, points: torch.Tensor) -> torch.Tensor:
        """:meth:`__call__` with autograd: the distances' gradient with respect to the points (zero outside the grid)."""
        flat = points.reshape(-1, 3).to(self.origin.device, torch.float32)
        normalised = (flat - self.origin) / self._extent * 2 - 1
        sampled = F.grid_sample(self._volume, normalised[None, None, None], mode="bilinear", align_corners=True)
        distances = sampled.reshape(-1)
        inside = ((normalised >= -1) & (normalised <= 1)).all(dim=-1)
        return torch.where(inside, distances, torch.full_like(distances, self.truncation)).reshape(points.shape[:-1]).to(points.dtype)

    def state(self) -> dict[str, Any]:
        """Plain data and tensors for the map file."""
        return {"origin": self.origin.cpu().clone(), "voxel": self.voxel, "truncation": self.truncation, "codes": self.codes.cpu().clone()}

    @classmethod
    def from_state(cls, state: Any) -> SurfaceDistance:
        """Inverse of :meth:`state`.

        Raises:
            MapFileError: for a record that is not a surface-distance layer (missing entries, wrong types or shapes).
        """
        try:
            return cls(
                torch.as_tensor(state["origin"], dtype=torch.float32),
                float(state["voxel"]),
                float(state["truncation"]),
                state["codes"] if isinstance(state["codes"], torch.Tensor) else torch.as_tensor(state["codes"]),
            )
        except (KeyError, TypeError, ValueError, RuntimeError) as error:
            raise MapFileError(f"surface distance layer: {error}; expected origin (3,), voxel, truncation and uint8 codes (Nz, Ny, Nx)") from None
