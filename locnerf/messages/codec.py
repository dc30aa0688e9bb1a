"""The codec: pydantic messages as msgpack envelopes, images as a msgpack header plus raw pixels.

Envelope (every message but images): ``msgpack({"v": SCHEMA_VERSION, "type": name, "body": {...}})``.
Image frame: ``u32 big-endian header length | msgpack envelope of an ImageHeader | H·W·3 bytes``,
then, for an RGB-D frame (the header's ``depth`` set), ``Hd·Wd·2`` bytes of little-endian uint16 millimetres.
A receiver checks the version, the type and the payload size; every failure raises
:class:`DecodeError` whose ``kind`` names the failure (for the services' bad-message counters).
"""

from __future__ import annotations

import struct
from typing import TypeVar

import msgpack
import numpy as np
from pydantic import BaseModel, ValidationError

from locnerf.messages.schemas import WIRE_TYPES, ImageHeader

SCHEMA_VERSION = 2
IMAGE_ENCODINGS = ("rgb8", "bgr8")
_LENGTH = struct.Struct(">I")

Message = TypeVar("Message", bound=BaseModel)


class DecodeError(ValueError):
    """A payload that cannot be turned into the expected message; ``kind`` is a short counter name."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(f"{kind}: {reason}")
        self.kind = kind
        self.reason = reason


def encode(message: BaseModel) -> bytes:
    """A message -> msgpack envelope bytes."""
    name = type(message).__name__
    if name not in WIRE_TYPES:
        raise ValueError(f"{name} is not a wire message type: expected one of {sorted(WIRE_TYPES)}")
    return msgpack.packb({"v": SCHEMA_VERSION, "type": name, "body": message.model_dump(mode="python")}, use_bin_type=True)


def _open_envelope(data: bytes, expected: type[Message]) -> Message:
    try:
        envelope = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except (ValueError, msgpack.UnpackException, TypeError) as error:
        raise DecodeError("undecodable", f"not a msgpack envelope ({error})") from None
    if not isinstance(envelope, dict) or not {"v", "type", "body"} <= envelope.keys():
        raise DecodeError("undecodable", "expected a map with keys v, type, body")
    if type(envelope["v"]) is not int or envelope["v"] != SCHEMA_VERSION:  # 1.0 and True equal 1 in Python
        raise DecodeError("schema_version", f"schema version {envelope['v']!r}, expected {SCHEMA_VERSION}")
    if envelope["type"] != expected.__name__:
        raise DecodeError("wrong_type", f"message type {envelope['type']!r}, expected {expected.__name__}")
    try:
        return expected.model_validate(envelope["body"])
    except ValidationError as error:
        raise DecodeError("invalid", f"{expected.__name__}: {error.errors()[0]['msg']} at {error.errors()[0]['loc']}") from None


def decode(data: bytes, expected: type[Message]) -> Message:
    """Envelope bytes -> a validated ``expected`` message.

    Raises:
        DecodeError: undecodable bytes, another schema version or type, or invalid fields.
    """
    return _open_envelope(data, expected)


def encode_image(header: ImageHeader, pixels: np.ndarray, depth: np.ndarray | None = None) -> bytes:
    """Header + pixels (H, W, 3) uint8 in the header's encoding (+ depth (Hd, Wd) uint16 millimetres
    when the header declares a depth image) -> frame bytes."""
    if header.encoding not in IMAGE_ENCODINGS:
        raise ValueError(f"image encoding {header.encoding!r}: expected one of {IMAGE_ENCODINGS}")
    if pixels.dtype != np.uint8 or pixels.shape != (header.height, header.width, 3):
        raise ValueError(f"image pixels: expected uint8 of shape ({header.height}, {header.width}, 3), got {pixels.dtype} {pixels.shape}")
    if (header.depth is None) != (depth is None):
        raise ValueError(f"depth image {'given' if depth is not None else 'missing'}: expected one exactly when the header declares depth")
    tail = b""
    if header.depth is not None and depth is not None:
        if depth.dtype != np.uint16 or depth.shape != (header.depth.height, header.depth.width):
            raise ValueError(f"depth pixels: expected uint16 of shape ({header.depth.height}, {header.depth.width}), got {depth.dtype} {depth.shape}")
        tail = np.ascontiguousarray(depth, dtype="<u2").tobytes()
    head = encode(header)
    return _LENGTH.pack(len(head)) + head + np.ascontiguousarray(pixels).tobytes() + tail


def decode_image(data: bytes, max_pixels: int | None = None) -> tuple[ImageHeader, np.ndarray]:
    """Frame bytes -> (header, pixels (H, W, 3) uint8 as RGB); an RGB-D frame's depth is checked and left out (see :func:`decode_rgbd`)."""
    header, pixels, _ = decode_rgbd(data, max_pixels)
    return header, pixels


def decode_rgbd(data: bytes, max_pixels: int | None = None) -> tuple[ImageHeader, np.ndarray, np.ndarray | None]:
    """Frame bytes -> (header, pixels (H, W, 3) uint8 as RGB, depth (Hd, Wd) uint16 millimetres or None).

    Args:
        max_pixels: refuse headers declaring more than this many pixels, colour or depth (None: no limit).

    Raises:
        DecodeError: as :func:`decode`, plus ``image_encoding``, ``image_too_large`` and ``image_size``.
    """
    if len(data) < _LENGTH.size:
        raise DecodeError("undecodable", f"image frame of {len(data)} bytes is shorter than its length prefix")
    (head_length,) = _LENGTH.unpack_from(data)
    if _LENGTH.size + head_length > len(data):
        raise DecodeError("undecodable", f"image header length {head_length} exceeds the frame ({len(data)} bytes)")
    header = _open_envelope(data[_LENGTH.size : _LENGTH.size + head_length], ImageHeader)
    if header.encoding not in IMAGE_ENCODINGS:
        raise DecodeError("image_encoding", f"encoding {header.encoding!r}, expected one of {IMAGE_ENCODINGS}")
    sizes = [(header.width, header.height)] + ([(header.depth.width, header.depth.height)] if header.depth is not None else [])
    for width, height in sizes:
        if max_pixels is not None and width * height > max_pixels:
            raise DecodeError("image_too_large", f"{width}×{height} pixels, at most {max_pixels} accepted")
    payload = memoryview(data)[_LENGTH.size + head_length :]
    colour_bytes = header.width * header.height * 3
    depth_bytes = header.depth.width * header.depth.height * 2 if header.depth is not None else 0
    if len(payload) != colour_bytes + depth_bytes:
        layout = f"{header.width}×{header.height}×3" + (f" + {header.depth.width}×{header.depth.height}×2 (depth)" if header.depth is not None else "")
        raise DecodeError("image_size", f"{len(payload)} pixel bytes, expected {colour_bytes + depth_bytes} for {layout}")
    pixels = np.frombuffer(payload[:colour_bytes], dtype=np.uint8).reshape(header.height, header.width, 3)
    pixels = pixels[..., ::-1].copy() if header.encoding == "bgr8" else pixels.copy()
    if header.depth is None:
        return header, pixels, None
    depth = np.frombuffer(payload[colour_bytes:], dtype="<u2").reshape(header.depth.height, header.depth.width).astype(np.uint16)
    return header, pixels, depth
