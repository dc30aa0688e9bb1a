"""The attachment rmw_zenoh puts on every publication, request and reply (design.md, "Publishers").

33 bytes, as ``zenoh::ext::Serializer`` writes them in ``attachment_helpers.cpp`` (rmw_zenoh ≥ 0.6,
the Kilted release line):

| offset | size | field |
|---|---|---|
| 0  | 8  | sequence number, int64 little-endian (per publisher, from 1) |
| 8  | 8  | source timestamp, int64 little-endian, nanoseconds since the UNIX epoch |
| 16 | 1  | length of the GID as a LEB128 varint: always 16, one byte ``0x10`` |
| 17 | 16 | publisher (or client) GID |
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from locnerf.messages.codec import DecodeError

GID_SIZE = 16
_HEAD = struct.Struct("<qqB")
SIZE = _HEAD.size + GID_SIZE


@dataclass(frozen=True)
class Attachment:
    """Metadata of one sample: ``sequence_number``, ``source_timestamp_ns``, ``gid`` (16 bytes)."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def __post_init__(self) -> None:
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"GID of {len(self.gid)} bytes: expected {GID_SIZE}")

    def encode(self) -> bytes:
        """The 33 attachment bytes."""
        return _HEAD.pack(self.sequence_number, self.source_timestamp_ns, GID_SIZE) + self.gid

    @classmethod
    def decode(cls, data: bytes | None) -> Attachment:
        """Parse attachment bytes.

        Raises:
            DecodeError: ``ros2_attachment`` for a missing attachment, a wrong size or GID length.
        """
        if data is None:
            raise DecodeError("ros2_attachment", "sample without an attachment (rmw_zenoh drops those too)")
        if len(data) != SIZE:
            raise DecodeError("ros2_attachment", f"attachment of {len(data)} bytes, expected {SIZE}")
        sequence, stamp, length = _HEAD.unpack_from(data)
        if length != GID_SIZE:
            raise DecodeError("ros2_attachment", f"GID length {length}, expected {GID_SIZE}")
        return cls(sequence, stamp, bytes(data[_HEAD.size :]))
