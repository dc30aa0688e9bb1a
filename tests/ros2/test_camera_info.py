"""CameraInfo -> the pinhole camera of the images, as image_proc rectifies them: D per model, P, R,
binning and region of interest; undistortion maps checked against OpenCV's projection of points."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from locnerf.messages.codec import DecodeError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2.camera_info import rectification_from_camera_info
from tests.ros2 import messages

RAW = PinholeIntrinsics(fx=60.0, fy=62.0, cx=40.0, cy=30.0, width=80, height=60)
PLUMB_BOB = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
P_RECTIFIED = np.array([[50.0, 0.0, 38.0, 0.0], [0.0, 51.0, 29.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def camera_info(distortion: np.ndarray | None = None, model: str = "plumb_bob", p: np.ndarray | None = None) -> object:
    """A CameraInfo of RAW with ``distortion`` of ``model`` and ``p`` (3, 4) (None: P = [K | 0])."""
    info = messages.camera_info(0.0, RAW, distortion=distortion)
    info.distortion_model = model
    if p is not None:
        info.p = p.reshape(-1)
    return info


def rectified_pixels(p: np.ndarray, step: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """A lattice of rectified pixels (N, 2) in the middle of the image and their rays (N, 3) through P⁻¹."""
    v, u = np.mgrid[10 : RAW.height - 10 : step, 10 : RAW.width - 10 : step]
    pixels = np.stack((u.reshape(-1), v.reshape(-1)), axis=1).astype(np.float64)
    rays = np.linalg.solve(p[:, :3], np.concatenate((pixels, np.ones((len(pixels), 1))), axis=1).T).T
    return pixels, rays


def test_camera_info_gives_intrinsics_and_rejects_a_zero_focal_length():
    camera = rectification_from_camera_info(camera_info())
    assert camera.intrinsics == RAW and camera.map_x is None, "no distortion and P = K: taken as it is"
    for field, value in (("k", np.zeros(9)), ("p", np.full(12, np.nan)), ("d", np.array([np.inf, 0, 0, 0, 0]))):
        info = camera_info()
        setattr(info, field, value)
        with pytest.raises(DecodeError) as error:
            rectification_from_camera_info(info)
        assert error.value.kind == "ros2_camera_info", field


@pytest.mark.parametrize(
    ("model", "count", "kind"),
    [
        ("plumb_bob", 5, None),
        ("plumb_bob", 4, None),
        ("plumb_bob", 3, "ros2_camera_info"),
        ("plumb_bob", 8, "ros2_camera_info"),
        ("rational_polynomial", 8, None),
        ("rational_polynomial", 14, None),
        ("rational_polynomial", 5, "ros2_camera_info"),
        ("equidistant", 4, None),
        ("equidistant", 5, "ros2_camera_info"),
        ("", 12, None),
        ("", 6, "ros2_camera_info"),
        ("kannala_brandt", 4, "ros2_camera_info_unsupported"),
    ],
)
def test_distortion_coefficients_are_checked_against_their_model(model, count, kind):
    """Lengths OpenCV accepts for the model (4, 5, 8, 12, 14; the fisheye model 4): the maps are made
    and an image is undistorted; any other length is a bad camera info, before any image meets OpenCV."""
    info = camera_info(np.full(count, 0.01), model)
    if kind is not None:
        with pytest.raises(DecodeError, match=repr(model)) as error:
            rectification_from_camera_info(info)
        assert error.value.kind == kind
        return
    camera = rectification_from_camera_info(info)
    assert camera.map_x is not None and camera.colour(np.zeros((60, 80, 3), np.uint8)).shape == (60, 80, 3)


def test_zero_coefficients_are_no_distortion_whatever_the_model():
    for model, count in (("kannala_brandt", 4), ("plumb_bob", 3), ("equidistant", 0)):
        assert rectification_from_camera_info(camera_info(np.zeros(count), model)).map_x is None, model


def test_a_raw_image_is_undistorted_onto_p_as_image_proc_does():
    """Oracle: the raw pixel that OpenCV's projectPoints gives for the ray of each rectified pixel
    (P⁻¹ [u, v, 1]) is where the map samples it, to 0.01 px (float32 maps); the intrinsics are P's."""
    camera = rectification_from_camera_info(camera_info(PLUMB_BOB, p=P_RECTIFIED))
    assert (camera.intrinsics.fx, camera.intrinsics.fy, camera.intrinsics.cx, camera.intrinsics.cy) == (50.0, 51.0, 38.0, 29.0)
    pixels, rays = rectified_pixels(P_RECTIFIED)
    raw, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), RAW.matrix().numpy(), PLUMB_BOB)
    u, v = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
    sampled = np.stack((camera.map_x[v, u], camera.map_y[v, u]), axis=1)
    assert np.abs(sampled - raw.reshape(-1, 2)).max() < 0.01
    # With P = K the image is what cv2.undistort makes of it (the previous behaviour), up to the
    # 1/32 px of its fixed-point maps: one level on a smooth image whose channels are 3u, 4v, u + v.
    v, u = np.mgrid[0:60, 0:80]
    smooth = np.stack((3 * u, 4 * v, u + v), axis=-1).astype(np.uint8)
    same = rectification_from_camera_info(camera_info(PLUMB_BOB)).colour(smooth).astype(int)
    assert np.abs(same - cv2.undistort(smooth, RAW.matrix().numpy(), PLUMB_BOB)).max() <= 1


def test_an_equidistant_camera_is_undistorted_with_the_fisheye_model():
    coefficients = np.array([0.05, -0.01, 0.002, -0.0005])
    camera = rectification_from_camera_info(camera_info(coefficients, "equidistant", p=P_RECTIFIED))
    pixels, rays = rectified_pixels(P_RECTIFIED)
    raw, _ = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), RAW.matrix().numpy(), coefficients)
    u, v = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
    assert np.abs(np.stack((camera.map_x[v, u], camera.map_y[v, u]), axis=1) - raw.reshape(-1, 2)).max() < 0.01


def test_a_rectified_image_is_taken_as_it_is_with_p():
    """image_rect is published with the raw camera's CameraInfo (non-zero D): undistorting it again,
    with K, was the bug. Its R is ignored (the image is already in the rectified frame)."""
    info = camera_info(PLUMB_BOB, p=P_RECTIFIED)
    info.r = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))[0].reshape(-1)
    camera = rectification_from_camera_info(info, rectified=True)
    pixels = np.random.default_rng(1).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    assert camera.map_x is None and camera.colour(pixels) is pixels
    assert camera.intrinsics == PinholeIntrinsics(fx=50.0, fy=51.0, cx=38.0, cy=29.0, width=80, height=60)


def test_a_raw_image_with_a_rectifying_rotation_is_refused_and_zero_r_or_p_are_unset():
    info = camera_info(PLUMB_BOB)
    info.r = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))[0].reshape(-1)
    with pytest.raises(DecodeError, match="R=") as error:
        rectification_from_camera_info(info)
    assert error.value.kind == "ros2_camera_info_unsupported"
    info.r, info.p = np.zeros(9), np.zeros(12)
    camera = rectification_from_camera_info(info)
    assert camera.intrinsics == RAW and camera.map_x is not None, "R unset is the identity, P unset is K"


def test_binning_and_a_region_of_interest_scale_and_shift_the_intrinsics():
    """By hand: fx / b, (cx - x_offset + 0.5) / b - 0.5 (pixel centres at integers; image_geometry's (cx - x_offset) / b
    is the corner convention's), the image roi.width / b wide."""
    info = camera_info(PLUMB_BOB, p=P_RECTIFIED)
    info.binning_x = info.binning_y = 2
    camera = rectification_from_camera_info(info)
    assert camera.intrinsics == PinholeIntrinsics(fx=25.0, fy=25.5, cx=18.75, cy=14.25, width=40, height=30)
    assert camera.map_x.shape == (30, 40)
    binned_p = P_RECTIFIED / np.array([[2.0], [2.0], [1.0]])
    binned_p[:2, 2] -= 0.25  # (c + 0.5) / 2 - 0.5
    pixels, rays = rectified_pixels(binned_p)
    inside = (pixels[:, 0] < 40) & (pixels[:, 1] < 30)
    pixels, rays = pixels[inside], rays[inside]
    raw, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), RAW.matrix().numpy(), PLUMB_BOB)
    u, v = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
    binned = np.stack(((camera.map_x[v, u]), camera.map_y[v, u]), axis=1)
    assert np.abs(binned * 2 + 0.5 - raw.reshape(-1, 2)).max() < 0.02, "binned raw pixel u' is sensor pixel 2u' + 0.5: the full map's point"
    info = camera_info()
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 8, 4, 32, 24
    info.binning_x = info.binning_y = 2
    assert rectification_from_camera_info(info).intrinsics == PinholeIntrinsics(fx=30.0, fy=31.0, cx=15.75, cy=12.75, width=16, height=12)
    info.d = PLUMB_BOB
    with pytest.raises(DecodeError, match="region of interest") as error:
        rectification_from_camera_info(info)
    assert error.value.kind == "ros2_camera_info_unsupported"
    info.d, info.roi.x_offset = np.zeros(5), 60
    with pytest.raises(DecodeError, match="outside") as error:
        rectification_from_camera_info(info)
    assert error.value.kind == "ros2_camera_info"


def test_depth_is_undistorted_with_the_colour_mapping_by_nearest_neighbour():
    """Each depth pixel encodes where it came from (1000 + column + 100 row); the colour undistortion
    of an image whose channels are the column and the row (bilinear) says where each output pixel
    samples. Nearest and bilinear sampling of the same mapping agree to one pixel, and nearest
    sampling invents no value (no depth between an object and its background)."""
    camera = rectification_from_camera_info(camera_info(PLUMB_BOB))
    rows, columns = np.mgrid[0:60, 0:80]
    depth = (1000 + columns + 100 * rows).astype(np.uint16)
    where = camera.colour(np.stack((columns, rows, np.zeros_like(rows)), axis=-1).astype(np.uint8)).astype(np.int64)
    undistorted = camera.depth(depth).astype(np.int64)
    inside = (undistorted > 0) & (where[..., 0] >= 1) & (where[..., 0] <= 78) & (where[..., 1] >= 1) & (where[..., 1] <= 58)
    assert inside.mean() > 0.8
    assert np.abs((undistorted[inside] - 1000) % 100 - where[..., 0][inside]).max() <= 1
    assert np.abs((undistorted[inside] - 1000) // 100 - where[..., 1][inside]).max() <= 1
    assert set(np.unique(undistorted)) <= set(np.unique(depth)) | {0}
    assert not np.array_equal(undistorted, depth), "the distortion moves pixels"
    assert rectification_from_camera_info(camera_info()).depth(depth) is depth
