"""Camera frame conventions.

Inside the library cameras follow NeRF/OpenGL axes: x right, y up, z backwards (the camera looks
along -z). OpenCV cameras use x right, y down, z forwards. Converting a camera-to-world pose between
the two flips the camera's y and z axes: ``T_world_cam_gl = T_world_cam_cv · diag(1, -1, -1, 1)``.
The pose of one camera in another camera's frame (an extrinsic between two cameras) changes axes on
both sides: ``T_a_b_gl = F · T_a_b_cv · F`` with ``F = diag(1, -1, -1, 1)``.
"""

from __future__ import annotations

import torch

_FLIP_YZ = (1.0, -1.0, -1.0, 1.0)


def _flip_camera_axes(pose: torch.Tensor) -> torch.Tensor:
    flip = torch.tensor(_FLIP_YZ, dtype=pose.dtype, device=pose.device)
    return pose * flip  # scales columns: right-multiplication by diag(flip)


def opencv_to_opengl(T_world_cam_cv: torch.Tensor) -> torch.Tensor:
    """Camera-to-world poses (..., 4, 4) with OpenCV camera axes -> OpenGL camera axes."""
    return _flip_camera_axes(T_world_cam_cv)


def opengl_to_opencv(T_world_cam_gl: torch.Tensor) -> torch.Tensor:
    """Camera-to-world poses (..., 4, 4) with OpenGL camera axes -> OpenCV camera axes."""
    return _flip_camera_axes(T_world_cam_gl)


def camera_extrinsic_opencv_to_opengl(T_a_b_cv: torch.Tensor) -> torch.Tensor:
    """Poses (..., 4, 4) of camera ``b`` in camera ``a``, both with OpenCV axes -> both with OpenGL axes.

    ``F · T · F`` with ``F = diag(1, -1, -1, 1)``: the rotation's entries that mix the flipped y, z
    axes with x change sign, and the translation is expressed in ``a``'s OpenGL axes (y, z negated).
    """
    flip = torch.tensor(_FLIP_YZ, dtype=T_a_b_cv.dtype, device=T_a_b_cv.device)
    return flip[:, None] * _flip_camera_axes(T_a_b_cv)  # scales rows: left-multiplication by diag(flip)
