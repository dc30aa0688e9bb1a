"""SO(3)/SE(3) maps, conversions, camera frames, rotation averaging and pose metrics (torch only)."""

from locnerf.geometry.averaging import (
    chordal_rotation_mean,
    geodesic_rotation_mean,
    project_to_rotation,
    tangent_covariance,
    weighted_pose_mean,
)
from locnerf.geometry.conversions import axis_angle_to_matrix, matrix_to_ypr, ypr_to_matrix
from locnerf.geometry.frames import camera_extrinsic_opencv_to_opengl, opencv_to_opengl, opengl_to_opencv
from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.geometry.quaternion import (
    matrix_to_quaternion,
    quaternion_to_matrix,
    quaternion_to_rotvec,
    rotvec_to_quaternion,
)
from locnerf.geometry.se3 import interpolate_pose, make_pose, pose_inverse, relative_pose, se3_exp, se3_log
from locnerf.geometry.so3 import hat, rotation_angle, so3_exp, so3_log, vee
from locnerf.geometry.validation import InvalidPoseError, validate_poses, validate_rotations

__all__ = [
    "InvalidPoseError",
    "axis_angle_to_matrix",
    "chordal_rotation_mean",
    "geodesic_rotation_mean",
    "hat",
    "interpolate_pose",
    "make_pose",
    "matrix_to_quaternion",
    "matrix_to_ypr",
    "ypr_to_matrix",
    "camera_extrinsic_opencv_to_opengl",
    "opencv_to_opengl",
    "opengl_to_opencv",
    "pose_inverse",
    "project_to_rotation",
    "quaternion_to_matrix",
    "quaternion_to_rotvec",
    "relative_pose",
    "rotation_angle",
    "rotation_error_deg",
    "rotvec_to_quaternion",
    "se3_exp",
    "se3_log",
    "so3_exp",
    "so3_log",
    "tangent_covariance",
    "translation_error",
    "validate_poses",
    "validate_rotations",
    "vee",
    "weighted_pose_mean",
]
