"""The map file: one ``torch.save`` archive holding backend kind, format version, weights and MapInfo.

Layout (a dict, loaded with ``weights_only=True`` so a map file cannot run code)::

    {"format": "locnerf-map", "version": 1, "kind": "grid" | "nerf_pytorch",
     "info": MapInfo.to_record(), "state": backend-specific weights and shapes}

Saving writes a temporary file beside the target and renames it into place, so an interrupted
save never leaves a half-written map under the target name.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Protocol

import torch

from locnerf.field.grid_map import GRID_KIND, GridMap
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import NERF_PYTORCH_KIND, NerfPytorchMap

FORMAT_NAME = "locnerf-map"
FORMAT_VERSION = 1
BACKENDS = {GRID_KIND: GridMap, NERF_PYTORCH_KIND: NerfPytorchMap}


class MapFileError(ValueError):
    """A map file that cannot be loaded: truncated, foreign, or written by a newer version."""


class SavableMap(Protocol):
    """What a backend offers the map file."""

    kind: str
    info: MapInfo

    def state(self) -> dict[str, Any]: ...


def save_map(radiance_map: SavableMap, path: str | Path) -> Path:
    """Write ``radiance_map`` to ``path`` atomically (temp file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    archive = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "kind": radiance_map.kind,
        "info": radiance_map.info.to_record(),
        "state": radiance_map.state(),
    }
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            torch.save(archive, stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def read_map_archive(path: str | Path) -> dict[str, Any]:
    """The checked archive dict of a map file (see the module docstring).

    Raises:
        FileNotFoundError: no such file.
        MapFileError: truncated/corrupt, not a locnerf map, newer format version, unknown backend.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"map file {path}: no such file")
    try:
        archive = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for truncated or foreign archives
        raise MapFileError(f"map file {path}: cannot be read as a locnerf map (truncated or not a map file: {error})") from error
    if not isinstance(archive, dict) or archive.get("format") != FORMAT_NAME:
        raise MapFileError(f"map file {path}: not a locnerf map (no '{FORMAT_NAME}' format tag)")
    version = archive.get("version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise MapFileError(f"map file {path}: format version {version!r} is newer than this locnerf reads ({FORMAT_VERSION}); upgrade locnerf")
    if archive.get("kind") not in BACKENDS:
        raise MapFileError(f"map file {path}: unknown backend kind {archive.get('kind')!r}, expected one of {sorted(BACKENDS)}")
    return archive


def load_map(path: str | Path, device: torch.device | str = "cpu") -> GridMap | NerfPytorchMap:
    """Load a map file onto ``device`` as its backend's RadianceMap."""
    archive = read_map_archive(path)
    info = MapInfo.from_record(archive["info"])
    return BACKENDS[archive["kind"]].from_state(archive["state"], info, torch.device(device))
