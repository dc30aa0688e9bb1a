"""Hostile payloads for every subscribed key, as Hypothesis strategies, each with the counter it must land in.

A strategy draws :class:`Hostile` payloads: the bytes, the name of the kind of damage, and the
bad-message kind the receiving service must count it under (``bad_<kind>`` in its status). The
expected kind is known by construction (a NaN pose is ``invalid``, a non-rigid odometry pose is
``invalid_odometry``), except for bit flips in an envelope's header, which can break it in several
ways: their kind is what :func:`locnerf.messages.codec.decode` says, and a flip the codec accepts
is reported as ``accepted`` (a failure: header flips never give a valid message).

Targets (:data:`TARGETS`) are the keys each service subscribes to: the filter's odometry, images,
update results and refusals and both commands; a worker's update requests; an ingest's ``filter/status`` (which
it reads while it waits for workers). Every payload is invalid: none re-initialises the filter or
makes a worker render.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np
from hypothesis import strategies as st
from pydantic import BaseModel

from locnerf.messages import keys
from locnerf.messages.codec import SCHEMA_VERSION, DecodeError, decode, decode_image
from locnerf.messages.schemas import (
    MAX_ABS_STAMP,
    WIRE_TYPES,
    FilterState,
    FilterStatus,
    GlobalLocalizationCommand,
    ImageHeader,
    InitialPoseCommand,
    Odometry,
    RefusalReason,
    UpdateRefusal,
    UpdateRequest,
    UpdateResult,
)
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.world import ProceduralWorld

ACCEPTED = "accepted"
"""Expected kind of a payload the codec took for a valid message (a failure of the fuzz run)."""

IMAGE_LIMIT_PIXELS = 4096 * 4096
"""The filter's default ``max_image_pixels``: oversized headers declare more."""

_EYE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
_COVARIANCE = [[1e-3 if i == j else 0.0 for j in range(6)] for i in range(6)]
_INTRINSICS = PinholeIntrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
_MAP_CHECKSUM = ProceduralWorld.default().checksum  # the fuzzed worker's map: a request's damage, not its map, is what it refuses
# msgpack prefixes declaring 2^32 − 1 entries or bytes: map32, array32, str32, bin32, ext32.
_HUGE_MARKERS = (b"\xdf\xff\xff\xff\xff", b"\xdd\xff\xff\xff\xff", b"\xdb\xff\xff\xff\xff", b"\xc6\xff\xff\xff\xff", b"\xc9\xff\xff\xff\xff\x01")


@dataclass(frozen=True)
class Hostile:
    """One payload: ``damage`` names how it was made, ``kind`` the bad-message kind it must be counted as."""

    damage: str
    payload: bytes
    kind: str


@dataclass(frozen=True)
class FuzzTarget:
    """A subscribed key of one service and the payloads thrown at it.

    ``counter_prefix`` is what the service puts before a kind (the filter counts commands as
    ``bad_command_<kind>``); ``drop_counters`` are the service's counters of messages it lets go
    unread by design (a full inbox, an image replaced by a newer one before it was read)."""

    service: str
    topic: keys.Topic
    fields: tuple[tuple[str, str], ...]
    counter_prefix: str
    drop_counters: tuple[str, ...]
    payloads: st.SearchStrategy[Hostile]

    def key(self, robot_id: str) -> str:
        """The full key expression."""
        return keys.key(robot_id, self.topic, **dict(self.fields))

    def counter(self, kind: str) -> str:
        """The status counter a payload of ``kind`` must increase."""
        return f"{self.counter_prefix}{kind}"


# ---------------------------------------------------------------------------------------------- envelopes
def _envelope(version: Any, type_name: str, body: Any) -> bytes:
    return msgpack.packb({"v": version, "type": type_name, "body": body}, use_bin_type=True)


def _header_length(type_name: str) -> int:
    """Bytes of an envelope before its body: map header, ``v``, ``type`` and its value, the ``body`` key."""
    return len(_envelope(SCHEMA_VERSION, type_name, None)) - 1


def _decode_kind(payload: bytes, message: type[BaseModel] | None) -> str:
    """The kind the codec gives ``payload`` (an image frame when ``message`` is None)."""
    try:
        decode_image(payload, IMAGE_LIMIT_PIXELS) if message is None else decode(payload, message)
    except DecodeError as error:
        return error.kind
    return ACCEPTED


def _flip(data: bytes, bits: list[int]) -> bytes:
    flipped = bytearray(data)
    for bit in bits:
        flipped[bit // 8] ^= 1 << (bit % 8)
    return bytes(flipped)


_finite = st.floats(-1e6, 1e6, allow_nan=False)
_stamps = st.floats(0.0, 1e6, allow_nan=False)
_absurd_stamps = st.one_of(st.floats(min_value=MAX_ABS_STAMP, allow_infinity=True), st.floats(max_value=-MAX_ABS_STAMP, allow_infinity=True), st.just(math.nan))
_not_finite = st.sampled_from([math.nan, math.inf, -math.inf])
_versions = st.one_of(
    st.integers(-(2**63), 2**64 - 1).filter(lambda v: v != SCHEMA_VERSION),
    st.floats(allow_nan=True),
    st.text(max_size=8),
    st.booleans(),
    st.none(),
)


def _rotation_rows(pose: list[list[float]], rotation: np.ndarray) -> list[list[float]]:
    rows = [list(map(float, rotation[i])) + [pose[i][3]] for i in range(3)]
    return rows + [[0.0, 0.0, 0.0, 1.0]]


@st.composite
def _non_rigid_pose(draw) -> list[list[float]]:
    """A finite 4×4 with last row [0, 0, 0, 1] whose rotation block is not a rotation (by > 0.01)."""
    entries = draw(st.lists(st.floats(-10.0, 10.0, allow_nan=False), min_size=9, max_size=9))
    rotation = np.array(entries).reshape(3, 3)
    if np.abs(rotation.T @ rotation - np.eye(3)).max() < 0.01 and np.linalg.det(rotation) > 0:
        rotation = rotation * 1.5  # (a near-rotation drawn by chance: scale it off)
    translation = draw(st.lists(_finite, min_size=3, max_size=3))
    return _rotation_rows([[0, 0, 0, t] for t in translation], rotation)


@st.composite
def _not_finite_pose(draw) -> list[list[float]]:
    """The identity with one of its 16 entries NaN or ±inf."""
    index = draw(st.integers(0, 15))
    pose = [row[:] for row in _EYE]
    pose[index // 4][index % 4] = draw(_not_finite)
    return pose


@st.composite
def _not_psd_covariance(draw) -> list[list[float]]:
    """A symmetric 6×6 with a negative diagonal entry."""
    index = draw(st.integers(0, 5))
    covariance = [row[:] for row in _COVARIANCE]
    covariance[index][index] = -draw(st.floats(1e-3, 1e6))
    return covariance


def _envelope_damage(message: type[BaseModel], valid: st.SearchStrategy[BaseModel]) -> list[st.SearchStrategy[Hostile]]:
    """Damage any envelope can take: truncation, header bit flips, versions, types, huge lengths, extra fields, stamps."""
    name = message.__name__
    header = _header_length(name)

    def encoded(m: BaseModel) -> bytes:
        return _envelope(SCHEMA_VERSION, name, m.model_dump(mode="python"))

    truncated = valid.map(encoded).flatmap(lambda data: st.integers(0, len(data) - 1).map(lambda n: Hostile("truncated", data[:n], "undecodable")))
    flipped = st.tuples(valid.map(encoded), st.lists(st.integers(0, 8 * header - 1), min_size=1, max_size=3, unique=True)).map(
        lambda pair: (lambda data: Hostile("header_bit_flip", data, _decode_kind(data, message)))(_flip(*pair))
    )
    versions = st.tuples(_versions, valid).map(lambda pair: Hostile("schema_version", _envelope(pair[0], name, pair[1].model_dump()), "schema_version"))
    other_types = st.one_of(st.sampled_from(sorted(set(WIRE_TYPES) - {name})), st.text(max_size=24).filter(lambda t: t != name))
    wrong_type = st.tuples(other_types, valid).map(lambda pair: Hostile("wrong_type", _envelope(SCHEMA_VERSION, pair[0], pair[1].model_dump()), "wrong_type"))
    huge = st.tuples(st.booleans(), st.sampled_from(_HUGE_MARKERS), st.binary(max_size=32)).map(
        lambda t: Hostile("huge_length", (_envelope(SCHEMA_VERSION, name, None)[:header] if t[0] else b"") + t[1] + t[2], "undecodable")
    )
    extra = st.tuples(st.text(min_size=1, max_size=12), valid).map(
        lambda pair: Hostile("extra_field", _envelope(SCHEMA_VERSION, name, pair[1].model_dump() | {"x_" + pair[0]: 1}), "invalid")
    )
    damages = [truncated, flipped, versions, wrong_type, huge, extra]
    if "stamp" in message.model_fields:
        damages.append(
            st.tuples(_absurd_stamps, valid).map(
                lambda pair: Hostile("absurd_stamp", _envelope(SCHEMA_VERSION, name, pair[1].model_dump() | {"stamp": pair[0]}), "invalid")
            )
        )
    return damages


def _body(message: type[BaseModel], damage: str, kind: str, fields: st.SearchStrategy[dict[str, Any]], valid: st.SearchStrategy[BaseModel]):
    """Payloads whose body is a valid one with ``fields`` replaced."""
    return st.tuples(valid, fields).map(lambda pair: Hostile(damage, _envelope(SCHEMA_VERSION, message.__name__, pair[0].model_dump() | pair[1]), kind))


# ---------------------------------------------------------------------------------------------- valid bases
_odometry = st.builds(lambda s: Odometry(stamp=s, frame_id="odom", T_odom_body=_EYE), _stamps)
_result = st.builds(
    lambda rid, n, s: UpdateResult(
        request_id=rid, shard=0, worker_id="fuzz", epoch=0, generation=0, ids=list(range(n)), log_likelihoods=[-1.0] * n, compute_seconds=s
    ),
    st.text(max_size=16),
    st.integers(0, 8),
    st.floats(0, 10),
)
_refusal = st.builds(
    lambda rid, reason: UpdateRefusal(request_id=rid, shard=0, worker_id="fuzz", reason=reason, detail="fuzz", map_checksum=_MAP_CHECKSUM),
    st.text(max_size=16),
    st.sampled_from(list(RefusalReason)),
)
_initial_pose = st.builds(lambda s: InitialPoseCommand(stamp=s, T_world_cam=_EYE, covariance=_COVARIANCE), _stamps)
_global = st.builds(lambda s: GlobalLocalizationCommand(stamp=s), _stamps)
_request = st.builds(
    lambda rid, n: UpdateRequest(
        request_id=rid,
        shard=0,
        map_checksum=_MAP_CHECKSUM,
        epoch=0,
        generation=0,
        ids=list(range(n)),
        poses=[sum(_EYE, [])] * n,
        pixels=[[1.0, 1.0]],
        observed_rgb=[[0.5, 0.5, 0.5]],
        intrinsics=_INTRINSICS,
    ),
    st.text(max_size=16),
    st.integers(1, 8),
)
_status = st.builds(
    lambda s, w: FilterStatus(
        stamp=s, state=FilterState.RUNNING, rates_hz={"pose": 15.0}, update_latency_s=None, in_flight=0, workers=w, map_checksum="0" * 64, counters={}
    ),
    _stamps,
    st.lists(st.text(max_size=8), max_size=3),
)


# ---------------------------------------------------------------------------------------------- images
def _frame(header: dict[str, Any], pixels: bytes) -> bytes:
    head = _envelope(SCHEMA_VERSION, ImageHeader.__name__, header)
    return struct.pack(">I", len(head)) + head + pixels


def _header(stamp: float, width: int = 16, height: int = 12, encoding: str = "rgb8") -> dict[str, Any]:
    intrinsics = PinholeIntrinsics(fx=20.0, fy=20.0, cx=width / 2, cy=height / 2, width=width, height=height)
    return ImageHeader(stamp=stamp, encoding=encoding, width=width, height=height, intrinsics=intrinsics).model_dump()


_pixels = st.integers(0, 255).map(lambda v: bytes([v]) * (16 * 12 * 3))


def _image_payloads() -> st.SearchStrategy[Hostile]:
    valid = st.tuples(_stamps, _pixels).map(lambda pair: _frame(_header(pair[0]), pair[1]))
    header_length = 4 + _header_length(ImageHeader.__name__)
    damages = [
        st.binary(max_size=3).map(lambda data: Hostile("shorter_than_prefix", data, "undecodable")),
        st.tuples(st.integers(1 << 16, (1 << 32) - 1), st.binary(max_size=64)).map(
            lambda pair: Hostile("huge_header_length", struct.pack(">I", pair[0]) + pair[1], "undecodable")
        ),
        st.tuples(valid, st.integers(1, 16 * 12 * 3)).map(lambda pair: Hostile("truncated_pixels", pair[0][: -pair[1]], "image_size")),
        st.tuples(valid, st.binary(min_size=1, max_size=512)).map(lambda pair: Hostile("extra_pixels", pair[0] + pair[1], "image_size")),
        st.tuples(_stamps, st.integers(1, 64), st.integers(1, 64))
        .filter(lambda t: t[1] * t[2] != 16 * 12)
        .map(lambda t: Hostile("size_mismatch", _frame(_header(t[0], t[1], t[2]), bytes(16 * 12 * 3)), "image_size")),
        st.tuples(_stamps, st.integers(4097, 1 << 20), st.integers(4097, 1 << 20)).map(
            lambda t: Hostile("oversized", _frame(_header(t[0], t[1], t[2]), bytes(64)), "image_too_large")
        ),
        st.tuples(_stamps, st.text(max_size=8).filter(lambda e: e not in ("rgb8", "bgr8"))).map(
            lambda pair: Hostile("bad_encoding", _frame(_header(pair[0], encoding=pair[1]), bytes(16 * 12 * 3)), "image_encoding")
        ),
        _absurd_stamps.map(lambda s: Hostile("absurd_stamp", _frame(_header(0.0) | {"stamp": s}, bytes(16 * 12 * 3)), "invalid")),
        st.floats(-1e9, -1e6).map(lambda s: Hostile("too_old", _frame(_header(s), bytes(16 * 12 * 3)), "image_too_old")),
        st.tuples(valid, st.lists(st.integers(32, 8 * header_length - 1), min_size=1, max_size=3, unique=True)).map(
            lambda pair: (lambda data: Hostile("header_bit_flip", data, _decode_kind(data, None)))(_flip(*pair))
        ),
    ]
    return st.one_of(damages)


# ---------------------------------------------------------------------------------------------- targets
def _odometry_payloads() -> st.SearchStrategy[Hostile]:
    pose = lambda strategy: strategy.map(lambda p: {"T_odom_body": p})  # noqa: E731
    return st.one_of(
        _envelope_damage(Odometry, _odometry)
        + [
            _body(Odometry, "not_finite_pose", "invalid", pose(_not_finite_pose()), _odometry),
            _body(Odometry, "non_rigid_pose", "invalid_odometry", pose(_non_rigid_pose()), _odometry),
            _body(Odometry, "bad_covariance", "invalid", _not_psd_covariance().map(lambda c: {"covariance": c}), _odometry),
        ]
    )


def _result_payloads() -> st.SearchStrategy[Hostile]:
    mismatched = st.tuples(st.integers(0, 8), st.integers(0, 8)).filter(lambda t: t[0] != t[1])
    return st.one_of(
        _envelope_damage(UpdateResult, _result)
        + [
            _body(
                UpdateResult, "ids_vs_likelihoods", "invalid", mismatched.map(lambda t: {"ids": list(range(t[0])), "log_likelihoods": [0.0] * t[1]}), _result
            ),
            _result.map(lambda r: Hostile("unknown_request_id", _envelope(SCHEMA_VERSION, "UpdateResult", r.model_dump()), "unknown_request")),
        ]
    )


def _refusal_payloads() -> st.SearchStrategy[Hostile]:
    return st.one_of(
        _envelope_damage(UpdateRefusal, _refusal)
        + [_refusal.map(lambda r: Hostile("unknown_request_id", _envelope(SCHEMA_VERSION, "UpdateRefusal", r.model_dump()), "unknown_request"))]
    )


def _initial_pose_payloads() -> st.SearchStrategy[Hostile]:
    pose = lambda strategy: strategy.map(lambda p: {"T_world_cam": p})  # noqa: E731
    return st.one_of(
        _envelope_damage(InitialPoseCommand, _initial_pose)
        + [
            _body(InitialPoseCommand, "not_finite_pose", "invalid", pose(_not_finite_pose()), _initial_pose),
            _body(InitialPoseCommand, "non_rigid_pose", "invalid", pose(_non_rigid_pose()), _initial_pose),
            _body(InitialPoseCommand, "bad_covariance", "invalid", _not_psd_covariance().map(lambda c: {"covariance": c}), _initial_pose),
        ]
    )


def _request_payloads() -> st.SearchStrategy[Hostile]:
    flat = lambda strategy: strategy.map(lambda p: {"poses": [sum(p, [])]})  # noqa: E731
    return st.one_of(
        _envelope_damage(UpdateRequest, _request)
        + [
            _body(UpdateRequest, "not_finite_pose", "bad_request", flat(_not_finite_pose()).map(lambda f: f | {"ids": [0]}), _request),
            _body(UpdateRequest, "non_rigid_pose", "bad_request", flat(_non_rigid_pose()).map(lambda f: f | {"ids": [0]}), _request),
            _body(
                UpdateRequest,
                "pixels_outside",
                "bad_request",
                st.tuples(st.floats(16.0, 1e9), st.floats(-1e9, 1e9)).map(lambda uv: {"pixels": [list(uv)]}),
                _request,
            ),
            _body(UpdateRequest, "poses_vs_ids", "invalid", st.integers(2, 8).map(lambda n: {"ids": list(range(n)), "poses": [sum(_EYE, [])]}), _request),
        ]
    )


def _status_payloads() -> st.SearchStrategy[Hostile]:
    return st.one_of(
        _envelope_damage(FilterStatus, _status)
        + [_body(FilterStatus, "negative_in_flight", "invalid", st.integers(max_value=-1).map(lambda n: {"in_flight": max(n, -(2**63))}), _status)]
    )


_FILTER_DROPS = ("inbox_dropped",)
TARGETS: tuple[FuzzTarget, ...] = (
    FuzzTarget("filter", keys.ODOMETRY, (), "bad_", _FILTER_DROPS, _odometry_payloads()),
    FuzzTarget("filter", keys.IMAGE, (), "bad_", _FILTER_DROPS + ("images_replaced",), _image_payloads()),
    FuzzTarget("filter", keys.UPDATE_RESULT, (), "bad_", _FILTER_DROPS, _result_payloads()),
    FuzzTarget("filter", keys.UPDATE_REFUSAL, (), "bad_", _FILTER_DROPS, _refusal_payloads()),
    FuzzTarget("filter", keys.INITIAL_POSE, (), "bad_command_", _FILTER_DROPS, _initial_pose_payloads()),
    FuzzTarget("filter", keys.GLOBAL_LOCALIZATION, (), "bad_command_", _FILTER_DROPS, st.one_of(_envelope_damage(GlobalLocalizationCommand, _global))),
    FuzzTarget("worker", keys.UPDATE_REQUEST, (("worker_id", "fuzzed"),), "bad_", ("inbox_dropped",), _request_payloads()),
    FuzzTarget("ingest", keys.STATUS, (), "bad_", ("inbox_dropped",), _status_payloads()),
)
"""Every subscribed key; the worker is named ``fuzzed``, the ingest under test waits for workers."""
