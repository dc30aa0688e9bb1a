"""What every map file records besides its weights: frame, camera, reference poses, provenance."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch

from locnerf.field.map_state import entry, tensor_of_shape, validated
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.ndc import ndc_rays_from_world_rays, rays_facing_scene

NDC_NEAR_PLANE = 1.0
METRIC_FRAME_KEY = "metric_frame"
"""Metadata entry of a map built by structure from motion: whether its frame is metric and how its scale and up axis
were obtained (``metric``, ``scale``, ``scale_sources``, ``gravity``, ``up``, ``sfm_to_map``; :mod:`locnerf.sfm.pipeline`).
Maps built from posed data sets have none: their frame is the data set's own."""

FieldRenderer = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
"""field-space origins (R, 3), field-space directions (R, 3), world-frame directions (R, 3) -> rgb (R, 3)."""


def metric_frame_problem(metadata: dict[str, Any]) -> str | None:
    """Why a map's frame cannot take odometry in metres, or None when it can.

    Only a map whose ``metric_frame`` entry says ``metric: false`` (built by SfM without a scale source) is
    refused; maps without the entry (built from posed data sets, and every map file written before it) are
    in their data set's frame, as before.
    """
    frame = metadata.get(METRIC_FRAME_KEY)
    if not isinstance(frame, dict) or frame.get("metric", True):
        return None
    return (
        "the map was built by structure from motion without a metric scale (its units are the reconstruction's, not metres), so odometry in "
        "metres would move the particles by the wrong distances; rebuild it with a scale source: depth images in the capture, "
        "--trajectory FILE (odometry/VIO recorded with the capture), --known-distance FRAME_A FRAME_B METRES or --scale METRES_PER_UNIT "
        "(locnerf map build CAPTURE --sfm ..., docs/MAPS.md)"
    )


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
        """World-frame rays (R, 3) x2 -> rays in the field's space (NDC-warped for NDC maps).

        Raises:
            ValueError: for an NDC map, when a ray looks away from the scene (``d_z >= 0``: it has no NDC ray).
        """
        if not self.normalization.ndc:
            return origins, directions
        return ndc_rays_from_world_rays(origins, directions, self.intrinsics, NDC_NEAR_PLANE)

    def render_world_rays(self, origins: torch.Tensor, directions: torch.Tensor, render_field: FieldRenderer, background: torch.Tensor) -> torch.Tensor:
        """rgb (R, 3) of world-frame rays (R, 3) x2: ``render_field`` on their field-space rays.

        On an NDC map, rays that look away from the forward-facing scene (``d_z >= 0``, which NDC
        would mirror onto the scene) see none of it: they get ``background`` (3,), as any ray that
        misses the map does, and are not rendered.
        """
        if not self.normalization.ndc:
            return render_field(origins, directions, directions)
        colours = background.to(origins.device, origins.dtype).expand(origins.shape[0], 3).clone()
        facing = rays_facing_scene(directions).nonzero(as_tuple=True)[0]
        if len(facing):
            field_origins, field_directions = self.field_rays(origins[facing], directions[facing])
            colours[facing] = render_field(field_origins, field_directions, directions[facing]).to(colours.dtype)
        return colours

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
        """Inverse of :meth:`to_record`.

        Raises:
            MapFileError: for a record with a missing or mistyped entry, an invalid normalisation or
                camera, or reference poses that are not finite (K >= 1, 4, 4).
        """
        poses = entry(record, "reference_poses", torch.Tensor, "map info")
        return cls(
            normalization=validated(MapNormalization, entry(record, "normalization", dict, "map info"), "map info: normalization"),
            intrinsics=validated(PinholeIntrinsics, entry(record, "intrinsics", dict, "map info"), "map info: intrinsics"),
            reference_poses=tensor_of_shape(poses, (max(1, poses.shape[0]) if poses.dim() == 3 else 1, 4, 4), "map info: reference_poses").double(),
            metadata=dict(entry(record, "metadata", dict, "map info")),
        )
