"""What every map file records besides its weights: frame, camera, reference poses, provenance."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.ndc import ndc_rays_from_world_rays

NDC_NEAR_PLANE = 1.0


@dataclass
class MapInfo:
    """Shared description of a map.

    Attributes:
        normalization: map frame vs data-set frame, NDC flag, near/far.
        intrinsics: the training camera (also defines the NDC projection).
        reference_poses: (K, 4, 4) float64 camera-to-world poses the map was built from (map frame).
        metadata: provenance and training figures (data set, steps, held-out PSNR, ...).
    """

    normalization: MapNormalization
    intrinsics: PinholeIntrinsics
    reference_poses: torch.Tensor
    metadata: dict[str, Any] = field(default_factory=dict)

    def camera_bounds(self) -> torch.Tensor:
        """(2, 3) box of the reference camera centres, grown by 10 % of its size (at least 0.1 map units)."""
        centres = self.reference_poses[:, :3, 3]
        low, high = centres.amin(0), centres.amax(0)
        margin = torch.clamp(0.1 * (high - low), min=0.1)
        return torch.stack((low - margin, high + margin))

    def field_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World-frame rays (R, 3) x2 -> rays in the field's space (NDC-warped for NDC maps)."""
        if not self.normalization.ndc:
            return origins, directions
        return ndc_rays_from_world_rays(origins, directions, self.intrinsics, NDC_NEAR_PLANE)

    def to_record(self) -> dict[str, Any]:
        """Plain data for the map file."""
        return {
            "normalization": self.normalization.model_dump(mode="json"),
            "intrinsics": self.intrinsics.model_dump(mode="json"),
            "reference_poses": self.reference_poses.detach().cpu().double().clone(),
            "metadata": dict(self.metadata),
        }

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> MapInfo:
        """Inverse of :meth:`to_record`."""
        return cls(
            normalization=MapNormalization.model_validate(record["normalization"]),
            intrinsics=PinholeIntrinsics.model_validate(record["intrinsics"]),
            reference_poses=record["reference_poses"].double(),
            metadata=dict(record["metadata"]),
        )
