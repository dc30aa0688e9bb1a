"""Conversions between ROS 2 messages and locnerf tensors: poses, covariance order, images."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from locnerf.geometry.se3 import adjoint, make_pose, pose_inverse, se3_exp
from locnerf.geometry.so3 import so3_exp
from locnerf.messages.codec import DecodeError
from locnerf.ros2.convert import (
    covariance_from_ros,
    covariance_to_ros,
    millimetres_from_depth_image,
    nanoseconds,
    pixels_from_compressed,
    pixels_from_image,
    pose_from_message,
    pose_message,
    seconds,
    time_message,
)
from locnerf.ros2.types import message_class
from tests.ros2 import messages

YAW_90 = make_pose(so3_exp(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))


def test_pose_and_time_round_trip():
    assert torch.allclose(pose_from_message(pose_message(YAW_90)), YAW_90, atol=1e-12)
    message = pose_message(YAW_90)
    assert (message.orientation.z, message.orientation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    assert seconds(time_message(12_250_000_000)) == 12.25 and (time_message(-500_000_000).sec, time_message(-500_000_000).nanosec) == (-1, 500_000_000)
    # Whole nanoseconds cross exactly; float seconds near 1.7e9 s would move this stamp by 72 ns.
    stamp = time_message(1_700_000_000_123_456_789)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789) and nanoseconds(stamp) == 1_700_000_000_123_456_789
    message.orientation.w = message.orientation.z = 0.0
    with pytest.raises(DecodeError, match="non-zero quaternion"):
        pose_from_message(message)


def test_covariance_order_is_pinned_by_hand():
    """Pose yawed 90°: variance 4 on our body-x translation is ROS world y; 0.01 on our rotation
    about body x is ROS pitch (rotation about world y); 0.09 on yaw stays yaw (index 5)."""
    ours = torch.diag(torch.tensor([0.01, 0.0, 0.09, 4.0, 0.0, 0.0], dtype=torch.float64))
    ros = torch.tensor(covariance_to_ros(ours, YAW_90), dtype=torch.float64).reshape(6, 6)
    expected = torch.zeros(6, 6, dtype=torch.float64)
    expected[1, 1], expected[4, 4], expected[5, 5] = 4.0, 0.01, 0.09
    assert torch.allclose(ros, expected, atol=1e-12)
    assert torch.allclose(covariance_from_ros(ros.reshape(-1).tolist(), YAW_90), ours, atol=1e-12)
    with pytest.raises(DecodeError, match="36 finite"):
        covariance_from_ros([0.0] * 35, YAW_90)


def test_covariance_conversion_matches_sampled_perturbations():
    """Oracle: perturb the pose by δ ~ N(0, Σ) on the right and measure the world-frame position
    and small-angle rotation; with 20 000 seeded samples of σ ≤ 0.01 the sample covariance
    matches within 5 % of the largest variance (sampling error ~1 %)."""
    generator = torch.Generator().manual_seed(0)
    root = torch.randn(6, 6, generator=generator, dtype=torch.float64) * 0.004
    sigma = root @ root.T
    deltas = torch.randn(20_000, 6, generator=generator, dtype=torch.float64) @ torch.linalg.cholesky(sigma).T
    moved = YAW_90 @ se3_exp(deltas)
    position = moved[:, :3, 3] - YAW_90[:3, 3]
    relative = moved[:, :3, :3] @ YAW_90[:3, :3].T
    angle = torch.stack((relative[:, 2, 1] - relative[:, 1, 2], relative[:, 0, 2] - relative[:, 2, 0], relative[:, 1, 0] - relative[:, 0, 1]), -1) / 2
    samples = torch.cat((position, angle), dim=1)
    measured = samples.T @ samples / samples.shape[0]
    ros = torch.tensor(covariance_to_ros(sigma, YAW_90), dtype=torch.float64).reshape(6, 6)
    assert (measured - ros).abs().max() < 0.05 * ros.diagonal().max()


def test_adjoint_moves_a_right_perturbation_across_a_fixed_transform():
    generator = torch.Generator().manual_seed(1)
    offset = se3_exp(torch.randn(6, generator=generator, dtype=torch.float64))
    delta = 0.1 * torch.randn(6, generator=generator, dtype=torch.float64)
    left = YAW_90 @ se3_exp(delta) @ pose_inverse(offset)
    right = YAW_90 @ pose_inverse(offset) @ se3_exp(adjoint(offset) @ delta)
    assert torch.allclose(left, right, atol=1e-10)


def _image(encoding: str, pixels: np.ndarray, pad: int = 0) -> object:
    height, width = pixels.shape[:2]
    rows = pixels.reshape(height, -1)
    padded = np.concatenate((rows, np.zeros((height, pad), np.uint8)), axis=1)
    header = message_class("std_msgs/msg/Header")(stamp=time_message(0), frame_id="camera")
    return message_class("sensor_msgs/msg/Image")(
        header=header, height=height, width=width, encoding=encoding, is_bigendian=0, step=padded.shape[1], data=padded.reshape(-1)
    )


def test_raw_images_in_three_encodings_with_row_padding():
    rgb = np.random.default_rng(0).integers(0, 256, (4, 5, 3), dtype=np.uint8)
    assert np.array_equal(pixels_from_image(_image("rgb8", rgb, pad=3)), rgb)
    assert np.array_equal(pixels_from_image(_image("bgr8", rgb[..., ::-1].copy())), rgb)
    mono = pixels_from_image(_image("mono8", rgb[..., 0].copy(), pad=1))
    assert mono.shape == (4, 5, 3) and np.array_equal(mono[..., 2], rgb[..., 0])
    with pytest.raises(DecodeError) as error:
        pixels_from_image(_image("16UC1", rgb))
    assert error.value.kind == "ros2_encoding"
    short = _image("rgb8", rgb)
    short.step = 3
    with pytest.raises(DecodeError) as error:
        pixels_from_image(short)
    assert error.value.kind == "ros2_image_size"


def test_compressed_png_is_decoded_to_rgb_and_unknown_formats_raise():
    rgb = np.random.default_rng(1).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    compressed = message_class("sensor_msgs/msg/CompressedImage")(
        header=message_class("std_msgs/msg/Header")(stamp=time_message(0), frame_id="camera"), format="rgb8; png compressed bgr8", data=png.reshape(-1)
    )
    assert ok and np.array_equal(pixels_from_compressed(compressed), rgb)
    compressed.format = "theora"
    with pytest.raises(DecodeError, match="theora"):
        pixels_from_compressed(compressed)


def test_depth_images_in_millimetres_are_taken_as_they_are():
    millimetres = np.random.default_rng(2).integers(0, 65536, (4, 5), dtype=np.uint16)
    for encoding in ("16UC1", "mono16"):
        assert np.array_equal(millimetres_from_depth_image(messages.depth_image(0.0, millimetres, encoding)), millimetres)
    big_endian = messages.depth_image(0.0, millimetres)
    big_endian.is_bigendian, big_endian.data = 1, millimetres.astype(">u2").view(np.uint8).reshape(-1)
    assert np.array_equal(millimetres_from_depth_image(big_endian), millimetres)
    padded = messages.depth_image(0.0, millimetres)
    rows = np.concatenate((millimetres.astype("<u2").view(np.uint8), np.full((4, 3), 255, np.uint8)), axis=1)
    padded.step, padded.data = rows.shape[1], rows.reshape(-1)
    assert np.array_equal(millimetres_from_depth_image(padded), millimetres)


def test_depth_images_in_metres_become_millimetres_and_invalid_readings_zero():
    """By hand: 1.2344 m -> 1234 mm, 1.6 mm -> 2 mm, 0.4 mm rounds to 0 (no reading, as on the wire),
    65.534 m is the largest reading uint16 holds; 65.535 m, NaN, ±inf, 0 and negative readings are none."""
    metres = np.array([[1.2344, 0.0016, 65.534, 65.535], [np.nan, np.inf, -np.inf, -0.5], [0.0, 0.0004, 2.0, 1e9]], dtype=np.float32)
    expected = np.array([[1234, 2, 65534, 0], [0, 0, 0, 0], [0, 0, 2000, 0]], dtype=np.uint16)
    converted = millimetres_from_depth_image(messages.depth_image(0.0, metres, "32FC1"))
    assert converted.dtype == np.uint16 and np.array_equal(converted, expected)


def test_bad_depth_images_raise_with_their_kind():
    depth = messages.depth_image(0.0, np.ones((4, 5), np.uint16))
    depth.encoding = "8UC1"
    with pytest.raises(DecodeError, match="'8UC1'") as error:
        millimetres_from_depth_image(depth)
    assert error.value.kind == "ros2_depth_encoding"
    for field, value in (("step", 8), ("height", 5), ("width", 0)):
        short = messages.depth_image(0.0, np.ones((4, 5), np.uint16))
        setattr(short, field, value)
        with pytest.raises(DecodeError) as error:
            millimetres_from_depth_image(short)
        assert error.value.kind == "ros2_depth_size", field
