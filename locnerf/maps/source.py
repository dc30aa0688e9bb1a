"""Opening the map a command or service names, and the target views of single-image trials."""

from __future__ import annotations

from collections.abc import Iterator

import torch

from locnerf.field.protocol import RadianceMap
from locnerf.render.image import render_image
from locnerf.sim.world import ProceduralWorld

WORLD = "world"


def open_map(spec: str, device: torch.device) -> RadianceMap:
    """``world`` -> the default procedural world; anything else -> a map file."""
    if spec == WORLD:
        return ProceduralWorld.default(device)
    from locnerf.field.map_file import load_map

    return load_map(spec, device)


def map_identity(radiance_map: RadianceMap) -> str:
    """The map's checksum (:attr:`RadianceMap.checksum`), by which the filter tells the workers that hold its map.

    Raises:
        ValueError: a map without one (built in memory and never saved).
    """
    checksum = getattr(radiance_map, "checksum", None)
    if not checksum:
        raise ValueError(f"{type(radiance_map).__name__} has no checksum: expected the world or a map saved to or loaded from a map file")
    return checksum


def viewpoints(radiance_map: RadianceMap, count: int, generator: torch.Generator) -> list[torch.Tensor]:
    """``count`` camera poses (4, 4) float64 in the map frame from which the map is seen well.

    The world draws random plausible poses; a map file uses the camera poses it was built from,
    in a seeded random order (repeating them when it has fewer than ``count``).
    """
    if isinstance(radiance_map, ProceduralWorld):
        return [radiance_map.sample_camera_pose(generator) for _ in range(count)]
    stored = radiance_map.reference_poses()
    order = torch.randperm(stored.shape[0], generator=generator)
    return [stored[order[i % len(order)]].double() for i in range(count)]


def target_views(radiance_map: RadianceMap, count: int, generator: torch.Generator) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
    """``count`` (true pose (4, 4) float64, image (H, W, 3)) pairs rendered by the map itself, from :func:`viewpoints`."""
    for pose in viewpoints(radiance_map, count, generator):
        yield pose, render_image(radiance_map.render_rays, pose.to(radiance_map.device, torch.float32), radiance_map.default_intrinsics)
