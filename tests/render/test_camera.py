"""The pixel convention of PinholeIntrinsics: pixel centres at integer coordinates, and what resizing
and decimating an image do to the camera (hand-worked values, and OpenCV's resize as the oracle)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import camera_directions_from_pixels

CAMERA = PinholeIntrinsics(fx=6.0, fy=5.0, cx=4.0, cy=3.0, width=8, height=6)


def _direction(camera: PinholeIntrinsics, u: float, v: float) -> torch.Tensor:
    return camera_directions_from_pixels(torch.tensor([[u, v]], dtype=torch.float64), camera)[0]


def test_halving_keeps_the_ray_through_the_same_physical_point() -> None:
    half = CAMERA.scaled(0.5)
    # Hand-worked: f/2, and (c + 0.5)/2 - 0.5.
    assert (half.fx, half.fy, half.cx, half.cy, half.width, half.height) == (3.0, 2.5, 1.75, 1.25, 4, 3)
    # New pixel (0, 0) averages old pixels 0..1 x 0..1, whose centre is old (0.5, 0.5); new (3, 2) is old (6.5, 4.5).
    torch.testing.assert_close(_direction(half, 0.0, 0.0), _direction(CAMERA, 0.5, 0.5))
    torch.testing.assert_close(_direction(half, 3.0, 2.0), _direction(CAMERA, 6.5, 4.5))


@pytest.mark.parametrize(("width", "height", "factor"), [(8, 6, 0.5), (12, 9, 1 / 3), (640, 480, 0.25), (7, 5, 2.0)])
def test_scaled_follows_an_area_resize(width: int, height: int, factor: float) -> None:
    """Resize ramp images whose values are the pixel coordinates: each new pixel's value is then the old
    coordinate of its centre, and the ray through it must be the old camera's ray through that coordinate.
    (Integer factors only: for a fractional one an area resize averages the ramp's steps, which is not the
    footprint's centre.)"""
    camera = PinholeIntrinsics(fx=0.9 * width, fy=0.8 * width, cx=0.45 * width, cy=0.55 * height, width=width, height=height)
    small = camera.scaled(factor)
    columns = np.tile(np.arange(width, dtype=np.float64), (height, 1))
    rows = np.tile(np.arange(height, dtype=np.float64)[:, None], (1, width))
    interpolation = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
    old_u = cv2.resize(columns, (small.width, small.height), interpolation=interpolation)
    old_v = cv2.resize(rows, (small.width, small.height), interpolation=interpolation)
    v, u = np.mgrid[0 : small.height, 0 : small.width]
    new = camera_directions_from_pixels(torch.from_numpy(np.stack((u, v), axis=-1)).double(), small)
    old = camera_directions_from_pixels(torch.from_numpy(np.stack((old_u, old_v), axis=-1)), camera)
    # Bilinear upsampling clamps at the border, where it holds no coordinate: compare the interior there.
    inside = (slice(None), slice(None)) if factor < 1 else (slice(1, -1), slice(1, -1))
    torch.testing.assert_close(new[inside], old[inside], atol=1e-6, rtol=0)  # OpenCV's float32 weights


def test_decimation_keeps_pixel_zero() -> None:
    third = CAMERA.decimated(3)
    # image[::3, ::3] of 8×6 is 3×2; new pixel j is old pixel 3j: c/3, f/3.
    assert (third.fx, third.fy, third.cx, third.cy, third.width, third.height) == (2.0, 5.0 / 3.0, 4.0 / 3.0, 1.0, 3, 2)
    torch.testing.assert_close(_direction(third, 2.0, 1.0), _direction(CAMERA, 6.0, 3.0))
    with pytest.raises(ValueError, match="stride=0"):
        CAMERA.decimated(0)


def test_from_fov_is_centred_across_the_full_width() -> None:
    camera = PinholeIntrinsics.from_fov(100, 60, math.radians(90))
    assert (camera.cx, camera.cy, camera.fx) == (49.5, 29.5, pytest.approx(50.0))
    # The image's left and right edges (u = -0.5 and W - 0.5) are ±45 degrees off the axis.
    left, right = _direction(camera, -0.5, 29.5), _direction(camera, 99.5, 29.5)
    assert float(torch.atan2(right[0], -right[2])) == pytest.approx(math.radians(45))
    assert float(torch.atan2(left[0], -left[2])) == pytest.approx(-math.radians(45))
