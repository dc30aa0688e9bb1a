"""Quaternion, rotation-vector, yaw-pitch-roll and camera-frame conversions."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.geometry import (
    camera_extrinsic_opencv_to_opengl,
    make_pose,
    matrix_to_quaternion,
    matrix_to_ypr,
    opencv_to_opengl,
    opengl_to_opencv,
    pose_inverse,
    quaternion_to_matrix,
    quaternion_to_rotvec,
    rotvec_to_quaternion,
    so3_exp,
    ypr_to_matrix,
)


def random_rotations(count: int, generator: torch.Generator) -> torch.Tensor:
    q = torch.randn(count, 4, dtype=torch.float64, generator=generator)
    return quaternion_to_matrix(q)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_matrix_quaternion_round_trip(dtype, tol, generator):
    rotations = random_rotations(1000, generator).to(dtype)
    q = matrix_to_quaternion(rotations)
    assert (q[:, 0] >= 0).all()
    assert (quaternion_to_matrix(q) - rotations).abs().max() < tol


def test_quaternion_extraction_near_half_turns():
    # Rotations by π about each axis have w = 0: the trace formula would divide by zero.
    rotations = so3_exp(torch.tensor([[math.pi, 0, 0], [0, math.pi, 0], [0, 0, math.pi]], dtype=torch.float64))
    assert (quaternion_to_matrix(matrix_to_quaternion(rotations)) - rotations).abs().max() < 1e-12


def test_quaternion_and_rotvec_agree_with_exp(generator):
    rotvec = torch.randn(300, 3, dtype=torch.float64, generator=generator)
    assert (quaternion_to_matrix(rotvec_to_quaternion(rotvec)) - so3_exp(rotvec)).abs().max() < 1e-12
    q = rotvec_to_quaternion(rotvec)
    assert (so3_exp(quaternion_to_rotvec(q)) - so3_exp(rotvec)).abs().max() < 1e-12


def test_known_quaternion():
    # 90° about z: q = (cos 45°, 0, 0, sin 45°); maps x to y.
    q = torch.tensor([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], dtype=torch.float64)
    rotated_x = quaternion_to_matrix(q) @ torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    assert torch.allclose(rotated_x, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), atol=1e-15)


def test_ypr_matches_elementary_product_and_round_trips(generator):
    yaw, pitch, roll = 0.7, -0.4, 1.1
    rz = torch.tensor([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]], dtype=torch.float64)
    ry = torch.tensor([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]], dtype=torch.float64)
    rx = torch.tensor([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]], dtype=torch.float64)
    ypr = torch.tensor([yaw, pitch, roll], dtype=torch.float64)
    assert torch.allclose(ypr_to_matrix(ypr), rz @ ry @ rx, atol=1e-15)
    angles = (torch.rand(500, 3, dtype=torch.float64, generator=generator) - 0.5) * torch.tensor(
        [2 * math.pi, math.pi * 0.99, 2 * math.pi], dtype=torch.float64
    )
    assert (matrix_to_ypr(ypr_to_matrix(angles)) - angles).abs().max() < 1e-9


def test_ypr_gimbal_lock_still_reconstructs_the_rotation():
    locked = ypr_to_matrix(torch.tensor([0.3, math.pi / 2, 0.2], dtype=torch.float64))
    assert torch.allclose(ypr_to_matrix(matrix_to_ypr(locked)), locked, atol=1e-9)


def test_camera_frame_conversion_flips_y_and_z(generator):
    pose_cv = make_pose(random_rotations(5, generator), torch.randn(5, 3, dtype=torch.float64, generator=generator))
    pose_gl = opencv_to_opengl(pose_cv)
    assert torch.allclose(opengl_to_opencv(pose_gl), pose_cv)
    # OpenCV looks along +z of its camera, OpenGL along -z: the same world direction.
    assert torch.allclose(pose_cv[:, :3, 2], -pose_gl[:, :3, 2])
    assert torch.allclose(pose_cv[:, :3, 0], pose_gl[:, :3, 0])
    assert torch.allclose(pose_cv[:, :3, 3], pose_gl[:, :3, 3])


def test_camera_extrinsic_conversion_changes_the_axes_of_both_cameras(generator):
    """Oracle: the relative pose of two OpenGL camera poses, each converted from OpenCV on its own."""
    T_world_a_cv, T_world_b_cv = make_pose(random_rotations(2, generator), torch.randn(2, 3, dtype=torch.float64, generator=generator))
    expected = pose_inverse(opencv_to_opengl(T_world_a_cv)) @ opencv_to_opengl(T_world_b_cv)
    converted = camera_extrinsic_opencv_to_opengl(pose_inverse(T_world_a_cv) @ T_world_b_cv)
    assert torch.allclose(converted, expected, atol=1e-12)
    # By hand: 2 cm along OpenCV y (down) is 2 cm along -y (OpenGL up is -down).
    down = torch.eye(4, dtype=torch.float64)
    down[1, 3] = 0.02
    assert torch.allclose(camera_extrinsic_opencv_to_opengl(down)[:3, 3], torch.tensor([0.0, -0.02, 0.0], dtype=torch.float64))


def test_pose_inverse(generator):
    poses = make_pose(random_rotations(20, generator), torch.randn(20, 3, dtype=torch.float64, generator=generator))
    assert torch.allclose(pose_inverse(poses) @ poses, torch.eye(4, dtype=torch.float64).expand(20, 4, 4), atol=1e-12)
