"""Conversions between ROS 2 messages (rosbags objects) and locnerf's tensors and frames.

Covariances: locnerf's are in the tangent space on the right of the pose, ``T · Exp(δ)``, with
``δ = (φ, ρ)`` (rotation first, body axes). A ROS ``PoseWithCovariance`` orders its 6×6 row-major
covariance as ``(x, y, z, rotation about X, rotation about Y, rotation about Z)`` with fixed
(parent-frame) axes. To first order ``T · Exp(δ)`` moves the position by ``R ρ`` and rotates by
``R φ`` about the parent's axes, so ``ε_ros = A δ`` with ``A = [[0, R], [R, 0]]`` and
``Σ_ros = A Σ Aᵀ`` (and back with ``A⁻¹ = [[0, Rᵀ], [Rᵀ, 0]]``).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from locnerf.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from locnerf.geometry.se3 import make_pose
from locnerf.messages.codec import DecodeError
from locnerf.messages.stamps import NANOSECONDS_PER_SECOND, seconds_from_nanoseconds
from locnerf.ros2.types import message_class
from locnerf.sim.events import depth_millimetres

RAW_ENCODINGS = ("rgb8", "bgr8", "mono8")
COMPRESSED_FORMATS = ("jpeg", "png")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")


# ---------------------------------------------------------------- time
# Stamps cross this boundary as whole nanoseconds, exactly (locnerf.messages.stamps): through float
# seconds a stamp near 1.7e9 s would come back up to 119 ns off.
def time_message(stamp_ns: int) -> object:
    """Whole nanoseconds -> builtin_interfaces/msg/Time (sec, nanosec with 0 <= nanosec < 1e9), exactly."""
    sec, nanosec = divmod(stamp_ns, NANOSECONDS_PER_SECOND)
    return message_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def nanoseconds(time: object) -> int:
    """builtin_interfaces/msg/Time -> whole nanoseconds, exactly."""
    return time.sec * NANOSECONDS_PER_SECOND + time.nanosec


def seconds(time: object) -> float:
    """builtin_interfaces/msg/Time -> float seconds (the nearest double: for arithmetic, not to carry the stamp)."""
    return seconds_from_nanoseconds(nanoseconds(time))


def header(stamp_ns: int, frame_id: str) -> object:
    """std_msgs/msg/Header stamped ``stamp_ns`` whole nanoseconds."""
    return message_class("std_msgs/msg/Header")(stamp=time_message(stamp_ns), frame_id=frame_id)


# ---------------------------------------------------------------- poses
def pose_message(pose: torch.Tensor) -> object:
    """(4, 4) pose -> geometry_msgs/msg/Pose (quaternion x, y, z, w)."""
    pose = pose.double()
    w, x, y, z = matrix_to_quaternion(pose[:3, :3]).tolist()
    position = message_class("geometry_msgs/msg/Point")(*pose[:3, 3].tolist())
    return message_class("geometry_msgs/msg/Pose")(position=position, orientation=message_class("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w))


def transform_message(pose: torch.Tensor) -> object:
    """(4, 4) pose -> geometry_msgs/msg/Transform."""
    pose_msg = pose_message(pose)
    translation = message_class("geometry_msgs/msg/Vector3")(pose_msg.position.x, pose_msg.position.y, pose_msg.position.z)
    return message_class("geometry_msgs/msg/Transform")(translation=translation, rotation=pose_msg.orientation)


def pose_from_message(pose: object) -> torch.Tensor:
    """geometry_msgs/msg/Pose -> (4, 4) float64.

    Raises:
        DecodeError: ``ros2_invalid`` for a non-finite pose or a zero quaternion.
    """
    q = torch.tensor([pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z], dtype=torch.float64)
    t = torch.tensor([pose.position.x, pose.position.y, pose.position.z], dtype=torch.float64)
    if not (torch.isfinite(q).all() and torch.isfinite(t).all()) or float(torch.linalg.vector_norm(q)) < 1e-9:
        raise DecodeError(
            "ros2_invalid", f"pose with position {t.tolist()} and quaternion (w, x, y, z) {q.tolist()}: expected finite values and a non-zero quaternion"
        )
    return make_pose(quaternion_to_matrix(q), t)


def _tangent_to_ros(rotation: torch.Tensor) -> torch.Tensor:
    a = torch.zeros(6, 6, dtype=torch.float64)
    a[:3, 3:] = rotation.double()
    a[3:, :3] = rotation.double()
    return a


def covariance_to_ros(covariance: torch.Tensor, pose: torch.Tensor) -> np.ndarray:
    """(6, 6) covariance in locnerf's right tangent (rotation, translation) at ``pose`` (4, 4) ->
    (36,) float64, ROS row-major (x, y, z, roll, pitch, yaw about the parent's axes)."""
    a = _tangent_to_ros(pose[:3, :3])
    out = a @ covariance.double() @ a.T
    return (0.5 * (out + out.T)).reshape(-1).numpy()


def covariance_from_ros(values, pose: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`covariance_to_ros`: 36 ROS values at ``pose`` -> (6, 6) locnerf tangent.

    Raises:
        DecodeError: ``ros2_invalid`` for a covariance that is not 36 finite values.
    """
    flat = torch.tensor(np.array(values, dtype=np.float64))
    if flat.numel() != 36 or not torch.isfinite(flat).all():
        raise DecodeError("ros2_invalid", f"covariance of {flat.numel()} values: expected 36 finite values")
    a_inverse = _tangent_to_ros(pose[:3, :3]).T
    out = a_inverse @ flat.reshape(6, 6) @ a_inverse.T
    return 0.5 * (out + out.T)


# ---------------------------------------------------------------- images
def pixels_from_image(image: object) -> np.ndarray:
    """sensor_msgs/msg/Image (rgb8, bgr8 or mono8) -> RGB (H, W, 3) uint8.

    Raises:
        DecodeError: ``ros2_encoding`` for another encoding, ``ros2_image_size`` for a size mismatch.
    """
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(image.encoding)
    if channels is None:
        raise DecodeError("ros2_encoding", f"image encoding {image.encoding!r}, expected one of {RAW_ENCODINGS}")
    height, width, step = image.height, image.width, image.step
    data = np.asarray(image.data, dtype=np.uint8)
    if width == 0 or height == 0 or step < width * channels or data.size != step * height:
        raise DecodeError("ros2_image_size", f"{data.size} bytes for {width}×{height} {image.encoding} with step {step}")
    rows = data.reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    if image.encoding == "mono8":
        return np.repeat(rows, 3, axis=2)
    return np.ascontiguousarray(rows[..., ::-1] if image.encoding == "bgr8" else rows)


def millimetres_from_depth_image(image: object) -> np.ndarray:
    """sensor_msgs/msg/Image of depth -> (H, W) uint16 millimetres along the optical axis, 0 = no reading.

    ``16UC1`` and ``mono16`` are millimetres (REP 118; 0 stays "no reading"); ``32FC1`` is metres,
    rounded to millimetres (:func:`locnerf.sim.events.depth_millimetres`, as locnerf's own sources
    send depth): NaN, ±inf, readings <= 0 and readings beyond the 65.534 m that uint16 holds become 0.
    Rows may be padded (``step``); ``is_bigendian`` is honoured.

    Raises:
        DecodeError: ``ros2_depth_encoding`` for another encoding, ``ros2_depth_size`` when the data
            do not hold ``height`` rows of ``step`` bytes with ``width`` pixels each.
    """
    if image.encoding not in DEPTH_ENCODINGS:
        raise DecodeError("ros2_depth_encoding", f"depth image encoding {image.encoding!r}, expected one of {DEPTH_ENCODINGS}")
    floats = image.encoding == "32FC1"
    dtype = np.dtype(np.float32 if floats else np.uint16).newbyteorder(">" if image.is_bigendian else "<")
    height, width, step = image.height, image.width, image.step
    data = np.asarray(image.data, dtype=np.uint8)
    if width == 0 or height == 0 or step < width * dtype.itemsize or data.size != step * height:
        raise DecodeError("ros2_depth_size", f"{data.size} bytes for a {width}×{height} {image.encoding} depth image with step {step}")
    rows = data.reshape(height, step)[:, : width * dtype.itemsize]
    values = np.ascontiguousarray(rows).view(dtype).reshape(height, width)
    return depth_millimetres(torch.from_numpy(values.astype(np.float64))) if floats else values.astype(np.uint16)


def pixels_from_compressed(image: object) -> np.ndarray:
    """sensor_msgs/msg/CompressedImage (jpeg or png) -> RGB (H, W, 3) uint8 (decoded by OpenCV).

    Raises:
        DecodeError: ``ros2_encoding`` for another format or bytes OpenCV cannot decode.
    """
    fmt = image.format.lower()
    if not any(name in fmt for name in COMPRESSED_FORMATS):
        raise DecodeError("ros2_encoding", f"compressed image format {image.format!r}, expected one mentioning jpeg or png")
    decoded = cv2.imdecode(np.asarray(image.data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if decoded is None:
        raise DecodeError("ros2_encoding", f"{len(image.data)} bytes of format {image.format!r} could not be decoded")
    return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
