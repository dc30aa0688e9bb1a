"""The map file: a fixed header with a SHA-256 of the payload, then one ``torch.save`` archive.

A map file is untrusted input (it may come from anywhere): loading never runs code and refuses,
naming the reason, anything that is not an intact map of a version this locnerf reads.

Version 2 layout (big-endian)::

    offset  0  8 bytes   magic b"LOCNMAP\x00"
    offset  8  u32       format version (2)
    offset 12  u64       payload length, bytes
    offset 20  32 bytes  SHA-256 of the payload
    offset 52  payload   torch.save archive (a dict, loaded with ``weights_only=True``):
                         {"format": "locnerf-map", "version": 2, "kind": "grid" | "nerf_pytorch",
                          "info": MapInfo.to_record(), "state": backend-specific weights and shapes,
                          optionally "surface_distance": SurfaceDistance.state() (RGB-D maps)}

The checksum is verified before the archive is unpickled, so a damaged or edited payload is
refused before torch sees it. Version-1 files (the bare archive, no header) are still read; they
carry no checksum, so loading one logs a warning. ``weights_only=True`` refuses any pickled object
other than tensors and plain containers, whatever the version; torch's own message (which
suggests turning that protection off) is not passed on.

Saving writes a temporary file beside the target and renames it into place, so an interrupted
save never leaves a half-written map under the target name.

A map's identity is the SHA-256 (hex) of its payload (the whole file for version 1): a loaded or
saved map carries it as ``checksum``, and filter and workers compare it (docs/SERVICES.md).
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import pickle
import struct
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Protocol

import torch

from locnerf.errors import MapFileError
from locnerf.field.grid_map import GRID_KIND, GridMap
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import NERF_PYTORCH_KIND, NerfPytorchMap
from locnerf.field.surface_distance import SurfaceDistance

logger = logging.getLogger(__name__)

FORMAT_NAME = "locnerf-map"
FORMAT_VERSION = 2
MAGIC = b"LOCNMAP\x00"
HEADER = struct.Struct(">8sIQ32s")
BACKENDS = {GRID_KIND: GridMap, NERF_PYTORCH_KIND: NerfPytorchMap}


class SavableMap(Protocol):
    """What a backend offers the map file."""

    kind: str
    info: MapInfo
    surface_distance: SurfaceDistance | None
    checksum: str | None

    def state(self) -> dict[str, Any]: ...


def save_map(radiance_map: SavableMap, path: str | Path) -> Path:
    """Write ``radiance_map`` to ``path`` atomically (temp file in the same folder, then rename); the map's
    ``checksum`` becomes the file's, as :func:`load_map` would give it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    archive = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "kind": radiance_map.kind,
        "info": radiance_map.info.to_record(),
        "state": radiance_map.state(),
    }
    if radiance_map.surface_distance is not None:
        archive["surface_distance"] = radiance_map.surface_distance.state()
    buffer = io.BytesIO()
    torch.save(archive, buffer)
    payload = buffer.getvalue()
    digest = hashlib.sha256(payload)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(HEADER.pack(MAGIC, FORMAT_VERSION, len(payload), digest.digest()))
            stream.write(payload)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    radiance_map.checksum = digest.hexdigest()
    return path


def _payload_of(path: Path, data: bytes) -> tuple[bytes, int, str]:
    """(torch archive bytes, file format version, SHA-256 hex of the payload) of a map file's ``data``, checked against its header.

    Raises:
        MapFileError: foreign, truncated, newer version, checksum mismatch.
    """
    if data.startswith(b"PK\x03\x04"):  # a bare torch.save zip archive: version 1
        logger.warning("map file %s: format version 1 carries no checksum; re-save it (locnerf map build) for version 2", path)
        return data, 1, hashlib.sha256(data).hexdigest()
    if not data.startswith(MAGIC):
        raise MapFileError(f"map file {path}: not a locnerf map (no '{MAGIC.rstrip(bytes(1)).decode()}' header)")
    if len(data) < HEADER.size:
        raise MapFileError(f"map file {path}: truncated header ({len(data)} of {HEADER.size} bytes)")
    _, version, length, digest = HEADER.unpack_from(data)
    if version > FORMAT_VERSION:
        raise MapFileError(f"map file {path}: format version {version} is newer than this locnerf reads ({FORMAT_VERSION}); upgrade locnerf")
    if version < 2:
        raise MapFileError(f"map file {path}: format version {version} in a version-2 header")
    payload = data[HEADER.size :]
    if len(payload) != length:
        raise MapFileError(f"map file {path}: truncated or extended payload ({len(payload)} bytes, the header says {length})")
    if hashlib.sha256(payload).digest() != digest:
        raise MapFileError(f"map file {path}: checksum mismatch (SHA-256 of the payload differs from the header): damaged or tampered")
    return payload, version, digest.hex()


def read_map_archive(path: str | Path) -> dict[str, Any]:
    """The checked archive dict of a map file (see the module docstring).

    Raises:
        FileNotFoundError: no such file.
        MapFileError: truncated/corrupt, not a locnerf map, newer format version, checksum mismatch,
            objects that only code could rebuild, unknown backend.
    """
    return _checked_archive(path)[0]


def read_map_info(path: str | Path) -> tuple[dict[str, Any], MapInfo]:
    """(:func:`read_map_archive`'s archive, its checked :class:`MapInfo`), without building the backend.

    Raises:
        MapFileError: as :func:`read_map_archive`, and for a malformed info record.
    """
    archive = read_map_archive(path)
    try:
        return archive, MapInfo.from_record(archive.get("info"))
    except MapFileError as error:
        raise MapFileError(f"map file {path}: {error}") from None


def _checked_archive(path: str | Path) -> tuple[dict[str, Any], str]:
    """(:func:`read_map_archive`'s archive, the map's checksum: SHA-256 hex of the payload)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"map file {path}: no such file")
    payload, file_version, checksum = _payload_of(path, path.read_bytes())
    try:
        archive = torch.load(io.BytesIO(payload), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # torch's message advises loading with weights_only=False, i.e. running the file's code: not passed on.
        raise MapFileError(
            f"map file {path}: refused, the archive holds objects other than tensors and plain data "
            "(a pickled class or callable, which would run code when loaded); a locnerf map never needs them"
        ) from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile) as error:
        raise MapFileError(f"map file {path}: cannot be read as a locnerf map (truncated or not a map file: {type(error).__name__})") from None
    if not isinstance(archive, dict) or archive.get("format") != FORMAT_NAME:
        raise MapFileError(f"map file {path}: not a locnerf map (no '{FORMAT_NAME}' format tag)")
    version = archive.get("version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise MapFileError(f"map file {path}: format version {version!r} is newer than this locnerf reads ({FORMAT_VERSION}); upgrade locnerf")
    if version != file_version:
        raise MapFileError(f"map file {path}: archive version {version} inside a version-{file_version} file")
    if archive.get("kind") not in BACKENDS:
        raise MapFileError(f"map file {path}: unknown backend kind {archive.get('kind')!r}, expected one of {sorted(BACKENDS)}")
    return archive, checksum


def load_map(path: str | Path, device: torch.device | str = "cpu") -> GridMap | NerfPytorchMap:
    """Load a map file onto ``device`` as its backend's RadianceMap, its ``checksum`` the file's.

    Raises:
        MapFileError: besides :func:`read_map_archive`'s reasons, an archive whose info or state is
            malformed (a missing or mistyped entry, wrong shapes, a grid of more than
            ``MAX_GRID_VERTICES`` vertices), refused before the backend allocates what it sizes.
    """
    archive, checksum = _checked_archive(path)
    try:
        info = MapInfo.from_record(archive.get("info"))
        radiance_map = BACKENDS[archive["kind"]].from_state(archive.get("state"), info, torch.device(device))
        if "surface_distance" in archive:
            radiance_map.surface_distance = SurfaceDistance.from_state(archive["surface_distance"]).to(device)
    except MapFileError as error:
        raise MapFileError(f"map file {path}: {error}") from None
    radiance_map.checksum = checksum
    return radiance_map
