"""sensor_msgs/msg/CameraInfo -> the pinhole camera of the images and how to get there, as image_proc does.

A CameraInfo describes the full-resolution sensor: ``K`` and ``D`` of the raw (distorted) image,
``R`` (a stereo pair's rectification rotation) and ``P``, whose left 3×3 block is the camera
matrix of the *rectified* image. ``binning_x/y`` and ``roi`` say how the published image was
binned and cropped from the sensor. image_geometry (behind image_proc's rectify) rectifies a raw
image with ``cv::initUndistortRectifyMap(K, D, R, P)`` (``cv::fisheye::…`` for ``equidistant``),
both matrices shifted by the ROI's offset and divided by the binning; the rectified image then has
``P``'s intrinsics. Here:

* a **raw** image is undistorted with those maps onto ``P``'s camera (``K`` when ``P`` is all zeros,
  as some drivers send it); without distortion and with ``P`` equal to ``K`` it is taken as it is;
* an already **rectified** image (image_proc's ``image_rect``, ``image_rect_color``) is taken as it
  is, with ``P``'s intrinsics: never undistorted again;
* ``D`` must have a length its model defines and OpenCV accepts (``plumb_bob`` 4 or 5,
  ``rational_polynomial`` 8, 12 or 14, ``equidistant`` 4, an unnamed model any of these); an empty
  or all-zero ``D`` is no distortion whatever the model;
* refused as unsupported (``ros2_camera_info_unsupported``): another distortion model with non-zero
  coefficients; on a raw image a rotation ``R`` other than the identity (it would turn the image out
  of the camera's optical frame, which ``T_body_cam`` places; a rectified image's ``R`` is ignored:
  ``T_body_cam`` then places the rectified frame); a region of interest on a camera with distortion
  or whose ``P`` differs from ``K`` (image_proc then computes a rectified region of its own).
  An all-zero ``R`` counts as the identity (unset), as does an all-zero ``P`` (then ``K``).

Every problem raises :class:`DecodeError` when the CameraInfo arrives (``ros2_camera_info`` for a
malformed one), so the images that follow never meet an OpenCV error.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from locnerf.messages.codec import DecodeError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.ros2 import convert

STANDARD_LENGTHS = (4, 5, 8, 12, 14)
"""Coefficient counts of OpenCV's standard (Brown–Conrady, rational, thin prism, tilted) model."""
DISTORTION_LENGTHS = {"plumb_bob": (4, 5), "rational_polynomial": (8, 12, 14), "equidistant": (4,), "": STANDARD_LENGTHS}
"""Accepted lengths of non-zero D per distortion model (sensor_msgs/distortion_models.hpp)."""
UNSUPPORTED = "ros2_camera_info_unsupported"


@dataclass(frozen=True)
class Rectification:
    """How the images of one CameraInfo become pinhole images.

    Attributes:
        intrinsics: the pinhole camera of the images afterwards (binned and cropped as published).
        map_x, map_y: (H, W) float32 source columns and rows of each output pixel (OpenCV's remap
            tables); None when the images are taken as they are.
    """

    intrinsics: PinholeIntrinsics
    map_x: np.ndarray | None = None
    map_y: np.ndarray | None = None

    def colour(self, pixels: np.ndarray) -> np.ndarray:
        """RGB (H, W, 3) uint8 -> the pinhole image (bilinear; pixels from outside the image are 0)."""
        if self.map_x is None:
            return pixels
        return cv2.remap(pixels, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def depth(self, millimetres: np.ndarray) -> np.ndarray:
        """(H, W) uint16 depth -> the pinhole image, by nearest neighbour.

        The same pixel mapping as :meth:`colour`: a depth value is a point's distance along the
        optical axis, which undistortion (no rotation) does not change, and interpolating across an
        edge would invent depths between foreground and background. Pixels that map outside the
        image get 0, no reading.
        """
        if self.map_x is None:
            return millimetres
        return cv2.remap(millimetres, self.map_x, self.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _matrix(values: object, rows: int, columns: int, name: str) -> np.ndarray:
    """A finite (rows, columns) float64 matrix from a CameraInfo field, or ``ros2_camera_info``."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    if array.size != rows * columns or not np.isfinite(array).all():
        raise DecodeError("ros2_camera_info", f"camera info {name} of {array.size} values {array.tolist()}: expected {rows * columns} finite values")
    return array.reshape(rows, columns)


def _distortion(info: object) -> np.ndarray:
    """D as (N,) float64, checked against its model's lengths; (0,) when there is no distortion."""
    distortion = np.asarray(info.d, dtype=np.float64).reshape(-1)
    if not np.isfinite(distortion).all():
        raise DecodeError("ros2_camera_info", f"camera info D={distortion.tolist()}: expected finite coefficients")
    if not np.any(distortion != 0):
        return np.zeros(0)
    model = info.distortion_model
    lengths = DISTORTION_LENGTHS.get(model)
    if lengths is None:
        raise DecodeError(UNSUPPORTED, f"distortion model {model!r} with D={distortion.tolist()}: expected one of {sorted(DISTORTION_LENGTHS)}")
    if distortion.size not in lengths:
        raise DecodeError("ros2_camera_info", f"distortion model {model!r} with {distortion.size} coefficients: expected {' or '.join(map(str, lengths))}")
    return distortion


def _binned(matrix: np.ndarray, x_offset: int, y_offset: int, binning: tuple[int, int]) -> np.ndarray:
    """A 3×3 camera matrix of the sensor -> that of the published image: principal point shifted by
    the region's offset, rows 0 and 1 divided by the binning (image_geometry's K_binned, P_binned).

    Pixel centres sit at integer coordinates (:class:`PinholeIntrinsics`): binned pixel u' covers sensor
    pixels b·u' … b·u' + b − 1, centred at b·u' + (b − 1)/2, so c' = (c − offset + 0.5)/b − 0.5 (image_geometry's
    c/b holds for the corner convention only)."""
    out = matrix.copy()
    out[0, 2] -= x_offset - 0.5
    out[1, 2] -= y_offset - 0.5
    out[0] /= binning[0]
    out[1] /= binning[1]
    out[0, 2] -= 0.5
    out[1, 2] -= 0.5
    return out


def _intrinsics(matrix: np.ndarray, width: int, height: int, name: str) -> PinholeIntrinsics:
    try:
        return PinholeIntrinsics(fx=matrix[0, 0], fy=matrix[1, 1], cx=matrix[0, 2], cy=matrix[1, 2], width=width, height=height)
    except ValueError as error:
        raise DecodeError("ros2_camera_info", f"camera info {name}={matrix.reshape(-1).tolist()}, image {width}×{height}: {error}") from None


def rectification_from_camera_info(info: object, rectified: bool = False) -> Rectification:
    """sensor_msgs/msg/CameraInfo -> the :class:`Rectification` of its images (module docstring).

    Args:
        info: the CameraInfo (rosbags object).
        rectified: the images are already rectified (image_rect): taken as they are with P's intrinsics.

    Raises:
        DecodeError: ``ros2_camera_info`` for a malformed CameraInfo (non-finite or zero focal
            matrices, a D length its model does not have, a region outside the sensor),
            ``ros2_camera_info_unsupported`` for what is refused.
    """
    k, r, p = _matrix(info.k, 3, 3, "K"), _matrix(info.r, 3, 3, "R"), _matrix(info.p, 3, 4, "P")[:, :3]
    distortion = _distortion(info)
    if not np.any(p != 0):
        p = k  # P unset
    rotated = np.any(r != 0) and not np.allclose(r, np.eye(3), atol=1e-9)
    if rotated and not rectified:
        raise DecodeError(
            UNSUPPORTED,
            f"camera info R={r.reshape(-1).tolist()}: a raw image is undistorted without rotation (T_body_cam places its optical frame); "
            "use the rectified topic (image_rect, T_body_cam then places the rectified frame) or a monocular stream",
        )
    binning = (max(int(info.binning_x), 1), max(int(info.binning_y), 1))
    roi = info.roi
    cropped = (roi.x_offset, roi.y_offset, roi.width, roi.height) != (0, 0, 0, 0) and (roi.width, roi.height) != (info.width, info.height)
    if cropped and (distortion.size or not np.allclose(p, k)):
        raise DecodeError(
            UNSUPPORTED,
            f"camera info with region of interest {roi.width}×{roi.height} at ({roi.x_offset}, {roi.y_offset}) and a distortion or P≠K: "
            "image_proc rectifies it to a region of its own; publish the full image or its rectified region",
        )
    if cropped and (roi.x_offset + roi.width > info.width or roi.y_offset + roi.height > info.height or roi.width == 0 or roi.height == 0):
        raise DecodeError(
            "ros2_camera_info", f"region of interest {roi.width}×{roi.height} at ({roi.x_offset}, {roi.y_offset}) outside the {info.width}×{info.height} sensor"
        )
    offset = (roi.x_offset, roi.y_offset) if cropped else (0, 0)
    width, height = (roi.width, roi.height) if cropped else (info.width, info.height)
    width, height = width // binning[0], height // binning[1]
    k_image, p_image = _binned(k, *offset, binning), _binned(p, *offset, binning)
    intrinsics = _intrinsics(p_image, width, height, "P")
    if rectified or (not distortion.size and np.allclose(p_image, k_image)):
        return Rectification(intrinsics)
    _intrinsics(k_image, width, height, "K")  # a zero focal length in K as well
    return Rectification(intrinsics, *_maps(k_image, distortion, p_image, info.distortion_model, (width, height)))


def _maps(k: np.ndarray, distortion: np.ndarray, p: np.ndarray, model: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's undistortion maps from the raw camera (K, D) onto the pinhole camera P, (H, W) float32 each."""
    try:
        if model == "equidistant" and distortion.size:
            return cv2.fisheye.initUndistortRectifyMap(k, distortion, np.eye(3), p, size, cv2.CV_32FC1)
        return cv2.initUndistortRectifyMap(k, distortion if distortion.size else np.zeros(5), None, p, size, cv2.CV_32FC1)
    except cv2.error as error:
        raise DecodeError(
            "ros2_camera_info", f"OpenCV refused K={k.reshape(-1).tolist()}, D={distortion.tolist()}, P={p.reshape(-1).tolist()}: {error}"
        ) from None


class CameraSlot:
    """The newest camera of one CameraInfo topic, as a :class:`Rectification`. Drivers repeat the
    CameraInfo with every image: the undistortion maps are rebuilt only when the calibration changes,
    and a refused CameraInfo leaves the previous camera in place.

    Args:
        rectified: the images of this camera are already rectified (image_rect).
    """

    def __init__(self, rectified: bool) -> None:
        self.rectified = rectified
        self.camera: Rectification | None = None
        self._calibration: tuple | None = None

    def update(self, info: object) -> None:
        """Take ``info`` (sensor_msgs/msg/CameraInfo).

        Raises:
            DecodeError: as :func:`~locnerf.ros2.camera_info.rectification_from_camera_info`.
        """
        roi = info.roi
        calibration = (
            info.width,
            info.height,
            info.distortion_model,
            *(tuple(np.asarray(values, dtype=np.float64).tolist()) for values in (info.d, info.k, info.r, info.p)),
            info.binning_x,
            info.binning_y,
            (roi.x_offset, roi.y_offset, roi.width, roi.height, roi.do_rectify),
        )
        if calibration != self._calibration:
            self.camera = rectification_from_camera_info(info, self.rectified)
            self._calibration = calibration


def undistorted_colour(message: object, camera: Rectification | None, compressed: bool, info_topic: str) -> np.ndarray:
    """A colour sensor_msgs/Image (or CompressedImage when ``compressed``) -> RGB (H, W, 3) uint8 on
    ``camera``'s pinhole intrinsics (undistorted when the camera has distortion).

    Raises:
        DecodeError: ``ros2_no_camera_info`` (``camera`` None: no CameraInfo yet on ``info_topic``),
            ``ros2_encoding``, ``ros2_image_size`` (not the camera's size).
    """
    if camera is None:
        raise DecodeError("ros2_no_camera_info", f"image before any CameraInfo on {info_topic}")
    intrinsics = camera.intrinsics
    pixels = convert.pixels_from_compressed(message) if compressed else convert.pixels_from_image(message)
    if pixels.shape[:2] != (intrinsics.height, intrinsics.width):
        raise DecodeError("ros2_image_size", f"image {pixels.shape[1]}×{pixels.shape[0]}, camera info {intrinsics.width}×{intrinsics.height}")
    return camera.colour(pixels)


def undistorted_depth(message: object, camera: Rectification | None, info_topic: str, registered: bool) -> np.ndarray:
    """A depth sensor_msgs/Image -> (H, W) uint16 millimetres on ``camera``'s intrinsics (nearest-neighbour undistortion).

    ``registered``: the depth image is registered to the colour camera (``camera`` is the colour one).

    Raises:
        DecodeError: ``ros2_no_camera_info`` (no CameraInfo yet on ``info_topic``), ``ros2_depth_encoding``,
            ``ros2_depth_size`` (data that do not hold the image, or not the camera's size).
    """
    if camera is None:
        raise DecodeError("ros2_no_camera_info", f"depth image before any CameraInfo on {info_topic}")
    intrinsics = camera.intrinsics
    millimetres = convert.millimetres_from_depth_image(message)
    if millimetres.shape != (intrinsics.height, intrinsics.width):
        described = "the colour camera info (the depth image is registered to it)" if registered else "the depth camera info"
        raise DecodeError("ros2_depth_size", f"depth image {millimetres.shape[1]}×{millimetres.shape[0]}, {described} {intrinsics.width}×{intrinsics.height}")
    return camera.depth(millimetres)
