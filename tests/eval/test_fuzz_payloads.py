"""The fuzzer's payloads are what they claim: the codec's verdict matches each payload's kind.

Codec-level kinds (undecodable, schema_version, wrong_type, invalid, image_size, image_encoding,
image_too_large) must be exactly what the codec raises; service-level damage (a non-rigid pose, a
pixel outside the image, a never-issued request id, a too-old image) must decode cleanly, so that
the service's own check is what counts them. (Whether the services then count each payload under
its kind is checked with real processes: tests/integration/test_fuzz.py.)
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings

from locnerf.eval.fuzz_payloads import ACCEPTED, IMAGE_LIMIT_PIXELS, TARGETS, FuzzTarget, Hostile
from locnerf.messages.codec import DecodeError, decode, decode_image
from locnerf.messages.schemas import FilterStatus, GlobalLocalizationCommand, InitialPoseCommand, Odometry, UpdateRefusal, UpdateRequest, UpdateResult

MESSAGES = {
    "sensors/odom": Odometry,
    "sensors/image": None,
    "update/result": UpdateResult,
    "update/refusal": UpdateRefusal,
    "command/initial_pose": InitialPoseCommand,
    "command/global_localization": GlobalLocalizationCommand,
    "update/request/{worker_id}": UpdateRequest,
    "filter/status": FilterStatus,
}
SERVICE_KINDS = {"invalid_odometry", "bad_request", "unknown_request", "image_too_old"}
# Damage that decodes and that only the service's own check catches (the filter counts a non-rigid
# initial pose as command_invalid, the same counter as a schema failure).
SERVICE_CHECKED = {"non_rigid_pose", "not_finite_pose", "pixels_outside", "unknown_request_id", "too_old"}


def codec_kind(payload: bytes, message) -> str:
    try:
        decode_image(payload, IMAGE_LIMIT_PIXELS) if message is None else decode(payload, message)
    except DecodeError as error:
        return error.kind
    return ACCEPTED


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.topic.suffix)
def test_every_payload_is_of_its_kind(target: FuzzTarget) -> None:
    message = MESSAGES[target.topic.suffix]

    @settings(max_examples=150, database=None, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
    @given(target.payloads)
    def check(hostile: Hostile) -> None:
        verdict = codec_kind(hostile.payload, message)
        assert hostile.kind != ACCEPTED
        if hostile.kind in SERVICE_KINDS:
            assert verdict == ACCEPTED and hostile.damage in SERVICE_CHECKED, (hostile.damage, verdict)
        elif verdict == ACCEPTED:
            assert hostile.damage in SERVICE_CHECKED, (hostile.damage, hostile.kind)
        else:
            assert verdict == hostile.kind, (hostile.damage, hostile.kind, verdict)

    check()
