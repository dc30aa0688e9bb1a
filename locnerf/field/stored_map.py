"""What every map read from a map file answers from its :class:`MapInfo` alone."""

from __future__ import annotations

from typing import Any

import torch

from locnerf.field.map_info import MapInfo
from locnerf.field.protocol import MapNormalization
from locnerf.field.surface_distance import SurfaceDistance
from locnerf.render.camera import PinholeIntrinsics


class StoredMap:
    """Base of the map-file backends: frame, camera, provenance and reference poses from ``info``, and the
    surface-distance layer of maps built from depth images (None for the others)."""

    info: MapInfo
    surface_distance: SurfaceDistance | None = None
    checksum: str | None = None
    """The map's identity: SHA-256 (hex) of the map file's payload it was loaded from or last saved to; None before either."""

    @property
    def normalization(self) -> MapNormalization:
        return self.info.normalization

    @property
    def default_intrinsics(self) -> PinholeIntrinsics:
        return self.info.intrinsics

    @property
    def metadata(self) -> dict[str, Any]:
        """Provenance and training figures."""
        return self.info.metadata

    def camera_bounds(self) -> torch.Tensor:
        return self.info.camera_bounds()

    def reference_poses(self) -> torch.Tensor:
        """(K, 4, 4) float64 camera-to-world poses of the images the map was built from."""
        return self.info.reference_poses
