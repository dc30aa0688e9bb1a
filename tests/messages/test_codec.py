"""Wire codec: round trips of every message type and every kind of bad payload."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.messages import codec, keys, schemas
from locnerf.render.camera import PinholeIntrinsics

INTRINSICS = PinholeIntrinsics(fx=20.0, fy=20.0, cx=2.0, cy=1.5, width=4, height=3)
EYE = [[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, -1.0], [0.0, 0.0, 1.0, 2.0], [0.0, 0.0, 0.0, 1.0]]
COV = [[0.01 if i == j else 0.0 for j in range(6)] for i in range(6)]

REQUEST = schemas.UpdateRequest(
    request_id="r",
    shard=0,
    map_checksum="ab" * 32,
    epoch=1,
    generation=2,
    ids=[7],
    poses=[sum(EYE, [])],
    pixels=[[1.0, 2.0]],
    observed_rgb=[[0.1, 0.2, 0.3]],
    intrinsics=INTRINSICS,
)
RESULT = schemas.UpdateResult(request_id="r", shard=0, worker_id="w", epoch=1, generation=2, ids=[7], log_likelihoods=[-math.inf], compute_seconds=0.1)

EXAMPLES = [
    schemas.Odometry(stamp=1.5, frame_id="odom", T_odom_body=EYE, covariance=COV),
    schemas.PoseStamped(stamp=2.0, T_world_cam=EYE),
    schemas.PoseEstimate(stamp=2.0, T_world_cam=EYE, covariance=COV, particle_count=3, spread=0.1, effective_sample_size=2.5, mode="coarse", epoch=1),
    schemas.ParticleCloud(stamp=0.0, positions=[[0.0, 1.0, 2.0]], weights=[1.0]),
    schemas.FilterStatus(
        stamp=0.0,
        state="running",
        rates_hz={"pose": 15.0},
        update_latency_s=None,
        in_flight=0,
        workers=["a"],
        workers_on_another_map=["b"],
        map_checksum="ab" * 32,
        counters={"x": 1},
    ),
    REQUEST,
    RESULT,
    REQUEST.model_copy(update={"search": schemas.SearchRequest(mean=EYE, covariance=COV, config=CrossEntropyConfig(start_position=0.05), seed=9)}),
    RESULT.model_copy(update={"search": schemas.SearchFound(pose=EYE, log_likelihood=3.5, start_log_likelihood=1.0)}),
    schemas.UpdateRefusal(request_id="r", shard=1, worker_id="w", reason="failed", detail="OutOfMemoryError: CUDA out of memory", map_checksum="cd" * 32),
    schemas.InitialPoseCommand(stamp=0.0, T_world_cam=EYE, covariance=COV),
    schemas.GlobalLocalizationCommand(stamp=0.0),
    schemas.ServiceStatus(stamp=1.7e9, service="nerf_worker", instance="w", counters={"requests_answered": 3, "bad_messages": 0}),
]


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips(message):
    assert codec.decode(codec.encode(message), type(message)) == message


def test_every_wire_type_has_an_example():
    assert {type(m).__name__ for m in EXAMPLES} | {"ImageHeader"} == set(schemas.WIRE_TYPES)


def test_enum_fields_travel_as_their_plain_strings():
    """Pose mode and filter state are enums in Python and the same bare strings on the wire as before they were."""
    pose, status = EXAMPLES[2], EXAMPLES[4]
    pose_body = msgpack.unpackb(codec.encode(pose))["body"]
    status_body = msgpack.unpackb(codec.encode(status))["body"]
    assert type(pose_body["mode"]) is str and pose_body["mode"] == "coarse"
    assert type(status_body["state"]) is str and status_body["state"] == "running"
    assert codec.decode(codec.encode(status), schemas.FilterStatus).state is schemas.FilterState.RUNNING
    with pytest.raises(codec.DecodeError, match="invalid"):
        codec.decode(_envelope(status_body | {"state": "sleeping"}, name="FilterStatus"), schemas.FilterStatus)


def _header(encoding: str = "rgb8") -> schemas.ImageHeader:
    return schemas.ImageHeader(stamp=3.0, frame_id="cam", encoding=encoding, width=4, height=3, intrinsics=INTRINSICS)


def test_image_round_trip_and_bgr_conversion():
    pixels = np.arange(36, dtype=np.uint8).reshape(3, 4, 3)
    header, decoded = codec.decode_image(codec.encode_image(_header(), pixels))
    assert header == _header() and np.array_equal(decoded, pixels)
    _, from_bgr = codec.decode_image(codec.encode_image(_header("bgr8"), pixels))
    assert np.array_equal(from_bgr, pixels[..., ::-1])


def _envelope(body: dict, version: int = codec.SCHEMA_VERSION, name: str = "Odometry") -> bytes:
    return msgpack.packb({"v": version, "type": name, "body": body})


@pytest.mark.parametrize(
    ("payload", "kind"),
    [
        (b"\xc1garbage", "undecodable"),
        (msgpack.packb([1, 2, 3]), "undecodable"),
        (_envelope({"stamp": 0.0, "T_odom_body": EYE}, version=99), "schema_version"),
        (_envelope({"stamp": 0.0, "T_world_cam": EYE}, name="PoseStamped"), "wrong_type"),
        (_envelope({"stamp": 0.0, "T_odom_body": [[math.nan] * 4] * 4}), "invalid"),
        (_envelope({"stamp": math.inf, "T_odom_body": EYE}), "invalid"),
        (_envelope({"stamp": 0.0, "T_odom_body": EYE, "covariance": [[1.0] * 6] * 5 + [[-1.0] * 6]}), "invalid"),
        (_envelope({"stamp": 0.0, "T_odom_body": EYE, "covariance": [[-1.0 if i == j else 0.0 for j in range(6)] for i in range(6)]}), "invalid"),
    ],
    ids=["garbage", "not-a-map", "version", "type", "nan-pose", "inf-stamp", "asymmetric-covariance", "negative-covariance"],
)
def test_bad_payloads_raise_decode_errors_naming_their_kind(payload, kind):
    with pytest.raises(codec.DecodeError) as caught:
        codec.decode(payload, schemas.Odometry)
    assert caught.value.kind == kind


def test_image_with_wrong_payload_size_or_encoding_is_rejected():
    frame = codec.encode_image(_header(), np.zeros((3, 4, 3), np.uint8))
    with pytest.raises(codec.DecodeError) as short:
        codec.decode_image(frame[:-1])
    assert short.value.kind == "image_size"
    head = codec.encode(_header().model_copy(update={"encoding": "mono16"}))
    with pytest.raises(codec.DecodeError) as encoding:
        codec.decode_image(len(head).to_bytes(4, "big") + head + bytes(36))
    assert encoding.value.kind == "image_encoding"
    with pytest.raises(codec.DecodeError) as truncated:
        codec.decode_image(b"\x00\x00\x10\x00abc")
    assert truncated.value.kind == "undecodable"


def test_image_header_must_match_its_intrinsics():
    with pytest.raises(ValueError, match="does not match the intrinsics"):
        schemas.ImageHeader(stamp=0.0, encoding="rgb8", width=5, height=3, intrinsics=INTRINSICS)


def test_key_table_is_unique_and_parses_worker_tokens():
    suffixes = [topic.suffix for topic in keys.TABLE]
    assert len(suffixes) == len(set(suffixes))
    token = keys.key("r1", keys.WORKER_ALIVE, worker_id="host-12", device="cuda", map_checksum="ab" * 32)
    assert token == "locnerf/r1/alive/worker/host-12/cuda/" + "ab" * 32
    assert keys.parse_worker_token(token) == keys.WorkerToken("host-12", "cuda", "ab" * 32)
    with pytest.raises(ValueError, match="<worker_id>/<device>/<map_checksum>"):
        keys.parse_worker_token("locnerf/r1/alive/worker/host-12/cuda")  # a token without a map
    with pytest.raises(ValueError, match="robot id"):
        keys.key("a/b", keys.POSE)
    assert "`filter/pose`" in keys.markdown_table()


@pytest.mark.parametrize("version", [float(codec.SCHEMA_VERSION), True, str(codec.SCHEMA_VERSION), codec.SCHEMA_VERSION - 1, codec.SCHEMA_VERSION + 1, None])
def test_only_the_integer_schema_version_is_accepted(version):
    body = schemas.GlobalLocalizationCommand(stamp=0.0).model_dump()
    payload = msgpack.packb({"v": version, "type": "GlobalLocalizationCommand", "body": body})
    with pytest.raises(codec.DecodeError) as error:
        codec.decode(payload, schemas.GlobalLocalizationCommand)
    assert error.value.kind == "schema_version"


@pytest.mark.parametrize("stamp", [1e10, -1e10, 1e300])
def test_absurd_stamps_are_invalid(stamp):
    payload = msgpack.packb({"v": codec.SCHEMA_VERSION, "type": "GlobalLocalizationCommand", "body": {"stamp": stamp, "frame_id": "map"}})
    with pytest.raises(codec.DecodeError) as error:
        codec.decode(payload, schemas.GlobalLocalizationCommand)
    assert error.value.kind == "invalid"


def test_image_headers_declaring_too_many_pixels_are_refused_unread():
    header = schemas.ImageHeader(stamp=0.0, encoding="rgb8", width=4, height=3, intrinsics=INTRINSICS)
    frame = codec.encode_image(header, np.zeros((3, 4, 3), dtype=np.uint8))
    assert codec.decode_image(frame, max_pixels=12)[0] == header
    with pytest.raises(codec.DecodeError) as error:
        codec.decode_image(frame, max_pixels=11)
    assert error.value.kind == "image_too_large"


DEPTH_INTRINSICS = PinholeIntrinsics(fx=11.0, fy=11.0, cx=1.0, cy=1.0, width=2, height=2)


def _rgbd_header() -> schemas.ImageHeader:
    return _header().model_copy(update={"depth": schemas.DepthHeader(width=2, height=2, intrinsics=DEPTH_INTRINSICS)})


def test_rgbd_frame_round_trips_its_depth_little_endian():
    pixels = np.arange(36, dtype=np.uint8).reshape(3, 4, 3)
    depth = np.array([[0, 1], [1000, 65534]], dtype=np.uint16)
    frame = codec.encode_image(_rgbd_header(), pixels, depth)
    assert frame[-8:] == depth.astype("<u2").tobytes()
    header, decoded, decoded_depth = codec.decode_rgbd(frame)
    assert header == _rgbd_header() and np.array_equal(decoded, pixels) and np.array_equal(decoded_depth, depth)
    assert decoded_depth.dtype == np.uint16
    assert np.array_equal(codec.decode_image(frame)[1], pixels)
    colour_only = codec.encode_image(_header(), pixels)
    assert codec.decode_rgbd(colour_only)[2] is None


def test_rgbd_frames_with_missing_depth_bytes_or_a_bad_depth_header_are_refused():
    pixels, depth = np.zeros((3, 4, 3), np.uint8), np.zeros((2, 2), np.uint16)
    frame = codec.encode_image(_rgbd_header(), pixels, depth)
    with pytest.raises(codec.DecodeError, match=r"expected 44 for 4×3×3 \+ 2×2×2 \(depth\)") as short:
        codec.decode_rgbd(frame[:-2])
    assert short.value.kind == "image_size"
    big_depth = schemas.DepthHeader(width=4, height=4, intrinsics=PinholeIntrinsics(fx=11.0, fy=11.0, cx=2.0, cy=2.0, width=4, height=4))
    big_frame = codec.encode_image(_header().model_copy(update={"depth": big_depth}), pixels, np.zeros((4, 4), np.uint16))
    with pytest.raises(codec.DecodeError) as large:
        codec.decode_rgbd(big_frame, max_pixels=12)  # the colour image (12 pixels) passes, the depth image (16) does not
    assert large.value.kind == "image_too_large"
    with pytest.raises(ValueError, match="depth encoding '32FC1'"):
        schemas.DepthHeader(encoding="32FC1", width=2, height=2, intrinsics=DEPTH_INTRINSICS)
    with pytest.raises(ValueError, match="depth image size 3×2 does not match"):
        schemas.DepthHeader(width=3, height=2, intrinsics=DEPTH_INTRINSICS)
    with pytest.raises(ValueError, match="expected one exactly when the header declares depth"):
        codec.encode_image(_header(), pixels, depth)
    with pytest.raises(ValueError, match="depth pixels: expected uint16 of shape"):
        codec.encode_image(_rgbd_header(), pixels, depth.astype(np.float32))


def test_a_depth_camera_offset_travels_with_the_depth_header_and_must_be_rigid():
    offset = [[1.0, 0.0, 0.0, 0.027], [0.0, 1.0, 0.0, 0.015], [0.0, 0.0, 1.0, 0.005], [0.0, 0.0, 0.0, 1.0]]
    header = _header().model_copy(update={"depth": schemas.DepthHeader(width=2, height=2, intrinsics=DEPTH_INTRINSICS, T_cam_depth=offset)})
    frame = codec.encode_image(header, np.zeros((3, 4, 3), np.uint8), np.ones((2, 2), np.uint16))
    assert codec.decode_rgbd(frame)[0].depth.T_cam_depth == offset
    sheared = [row[:] for row in offset]
    sheared[0][1] = 0.2
    with pytest.raises(ValueError, match="T_cam_depth: expected a rigid transform"):
        schemas.DepthHeader(width=2, height=2, intrinsics=DEPTH_INTRINSICS, T_cam_depth=sheared)
    with pytest.raises(ValueError, match="T_cam_depth: expected a 4×4 matrix"):
        schemas.DepthHeader(width=2, height=2, intrinsics=DEPTH_INTRINSICS, T_cam_depth=offset[:3])


def test_stamps_carry_whole_nanoseconds_exactly_and_must_agree_with_the_seconds():
    exact = 1_700_000_000_123_456_789  # float seconds hold 1_700_000_000.1234567165...: 72 ns off
    odometry = codec.decode(codec.encode(schemas.Odometry(stamp_ns=exact, T_odom_body=EYE)), schemas.Odometry)
    assert odometry.stamp_ns == exact and odometry.stamp == 1_700_000_000.1234567
    assert schemas.Odometry(stamp=0.1, T_odom_body=EYE).stamp_ns == 100_000_000, "the nanoseconds of a float stamp are derived"
    for body in ({"stamp": 1.0, "stamp_ns": 1_000_002_000}, {"stamp_ns": 10**19}, {"stamp_ns": 1.5}):
        with pytest.raises(codec.DecodeError) as error:
            codec.decode(_envelope(body | {"T_odom_body": EYE}), schemas.Odometry)
        assert error.value.kind == "invalid", body


def test_search_parts_must_carry_a_pose_a_six_by_six_covariance_and_a_bounded_budget():
    sheared = [row[:] for row in EYE]
    sheared[3] = [0.0, 0.0, 0.0, 2.0]
    with pytest.raises(ValueError, match=r"pose: expected last row \[0, 0, 0, 1\]"):
        schemas.SearchRequest(mean=sheared, covariance=COV, config=CrossEntropyConfig(), seed=1)
    with pytest.raises(ValueError, match="covariance: expected a 6×6 matrix"):
        schemas.SearchRequest(mean=EYE, covariance=[row[:5] for row in COV], config=CrossEntropyConfig(), seed=1)
    with pytest.raises(ValueError, match="elite=9 > candidates=8"):
        schemas.SearchRequest(mean=EYE, covariance=COV, config={"candidates": 8, "elite": 9}, seed=1)
    with pytest.raises(ValueError, match="less than or equal to 50"):  # a worker is not held for hours
        schemas.SearchRequest(mean=EYE, covariance=COV, config={"iterations": 10**9}, seed=1)
    with pytest.raises(ValueError, match="less than or equal to 4096"):
        schemas.SearchRequest(mean=EYE, covariance=COV, config={"candidates": 10**7}, seed=1)
    with pytest.raises(ValueError, match="pose: expected finite entries"):
        schemas.SearchFound(pose=[[math.nan] * 4] * 3 + [[0.0, 0.0, 0.0, 1.0]], log_likelihood=0.0, start_log_likelihood=0.0)
