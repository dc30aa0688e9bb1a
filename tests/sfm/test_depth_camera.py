"""The depth camera found from SfM-like points in the colour camera's frame and the depth images (locnerf.sfm.depth_camera)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from locnerf.data.colour_camera import colour_camera_of, with_colour_camera
from locnerf.errors import DatasetError
from locnerf.filter.depth_measurement import render_depth_image
from locnerf.geometry import pose_inverse, rotation_angle
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels
from locnerf.sfm.depth_camera import METADATA_RECORD, DepthView, calibrate_depth_camera, with_photometric_depth_camera
from locnerf.sim.world import ProceduralWorld
from tests.data.rgbd_world import DEPTH, FINE_TEXTURE, TRUE_OFFSET, pixel_shift, rgbd_sequence
from tests.sfm.world_capture import capture_poses


def _views(offset: torch.Tensor, noise_m: float, frames: int = 8, per_view: int = 400) -> list[DepthView]:
    """Depth images from the depth cameras ``poses``; each view's points are surface points read from the *next*
    frame's depth image (so not at this image's pixel centres), in this frame's colour camera (``pose · offset``), plus noise."""
    world = ProceduralWorld()
    poses = capture_poses(frames)
    depths = [render_depth_image(world.render_surface, pose, DEPTH).depth for pose in poses]
    generator = torch.Generator().manual_seed(0)
    pixels = pixel_grid(DEPTH).double()
    views = []
    for k, pose in enumerate(poses):
        other = (k + 1) % frames
        origins, directions = rays_from_poses_and_pixels(poses[other][None], pixels, DEPTH)
        z = depths[other].double().reshape(-1)
        forward = -poses[other][:3, 2]
        world_points = origins.reshape(-1, 3) + directions.reshape(-1, 3) * (z / (directions.reshape(-1, 3) @ forward))[:, None]
        chosen = torch.nonzero(z > 0).reshape(-1)
        chosen = chosen[torch.randperm(len(chosen), generator=generator)[:per_view]]
        colour = pose_inverse(pose @ offset)
        local = world_points[chosen] @ colour[:3, :3].T + colour[:3, 3]
        local = local + noise_m * torch.randn(local.shape, generator=generator, dtype=torch.float64)
        views.append(DepthView(local[local[:, 2] < -0.1], depths[k], DEPTH))
    return views


@pytest.mark.parametrize("noise_m", [0.0, 0.005])
def test_the_known_colour_depth_offset_comes_back(noise_m):
    """The procedural room seen by a depth camera 3.1 cm / 0.8 deg from the colour camera (the redkitchen Kinect's):
    the calibration finds the offset within 2 mm and 0.1 deg (points exact or with 5 mm noise); the residuals fall."""
    calibration = calibrate_depth_camera(_views(TRUE_OFFSET, noise_m))
    error = pose_inverse(TRUE_OFFSET) @ calibration.T_depth_colour
    assert float(error[:3, 3].norm()) < 0.002, calibration.T_depth_colour
    assert math.degrees(float(rotation_angle(error[:3, :3]))) < 0.1, calibration.T_depth_colour
    assert calibration.residual_after_m < calibration.residual_before_m and calibration.views == 8
    record = calibration.record()
    assert record["translation_m"] == pytest.approx(float(TRUE_OFFSET[:3, 3].norm()), abs=0.002)


def test_points_that_meet_no_depth_reading_are_refused():
    views = _views(TRUE_OFFSET, 0.0, frames=3, per_view=20)
    far_away = [DepthView(view.points + torch.tensor([0.0, 0.0, -50.0], dtype=torch.float64), view.depth, view.intrinsics) for view in views]
    with pytest.raises(DatasetError, match="meet a depth reading"):
        calibrate_depth_camera(far_away)


def test_the_photometric_placement_brings_the_depth_points_close_to_the_true_camera() -> None:
    """Frames posed at their colour camera with depth images from the Kinect-like offset, as SfM poses an RGB-D capture:
    the photometric placement moves the depth camera off the colour camera toward the true one, so the depth points
    land within 2 px of where the true offset projects them, under a third of the 6 px they are off with the depth
    camera at the colour camera. Not all the way (one pass from the colour camera; measured when written: 1.66 px,
    11 mm and 0.47 degrees off the truth, as on the kitchen's SfM build: 11.7 mm and 0.57 degrees from the posed build's calibration)."""
    sequence = rgbd_sequence(ProceduralWorld(FINE_TEXTURE))
    colour_posed = replace(with_colour_camera(sequence, TRUE_OFFSET), T_cam_depth=None)
    placed, metadata = with_photometric_depth_camera(colour_posed)
    T_depth_colour = pose_inverse(placed.T_cam_depth)
    torch.testing.assert_close(colour_camera_of(metadata), T_depth_colour)
    assert (
        metadata[METADATA_RECORD]["method"] == "photometric"
        and metadata[METADATA_RECORD]["inconsistency_after"] < metadata[METADATA_RECORD]["inconsistency_before"]
    )
    at_colour = float(pixel_shift(sequence, torch.eye(4, dtype=torch.float64), TRUE_OFFSET).median())
    placed_shift = float(pixel_shift(sequence, T_depth_colour, TRUE_OFFSET).median())
    assert at_colour > 5.0 and placed_shift < 2.0 and placed_shift < at_colour / 3, (placed_shift, at_colour)
    assert with_photometric_depth_camera(colour_posed.without_depth()) == (colour_posed.without_depth(), {})
