"""A hand-held-like RGB-D pass through the procedural world whose colour camera sits off the depth camera (known offset)."""

from __future__ import annotations

import math

import torch

from locnerf.data.posed_images import PosedImages
from locnerf.field.protocol import MapNormalization
from locnerf.filter.depth_measurement import render_depth_image
from locnerf.filter.warp import project_points
from locnerf.geometry import make_pose, se3_exp, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import camera_directions_from_pixels
from locnerf.sim.textures import TextureConfig
from locnerf.sim.world import ProceduralWorld, WorldConfig

COLOUR = PinholeIntrinsics.from_fov(160, 120, math.radians(62))
DEPTH = PinholeIntrinsics.from_fov(120, 90, math.radians(57))
TRUE_OFFSET = make_pose(so3_exp(torch.tensor([0.012, -0.006, 0.004], dtype=torch.float64)), torch.tensor([0.027, 0.015, 0.005], dtype=torch.float64))
"""The colour camera in the depth camera's frame: about the redkitchen Kinect's (3 cm, 1.5 cm, 0.8 degrees)."""


def rgbd_sequence(world: ProceduralWorld, frames: int = 30) -> PosedImages:
    """A hand-held-like pass through the world: depth camera poses, colour images seen from ``pose · TRUE_OFFSET``, exact depth images."""
    start = world.sample_camera_pose(torch.Generator().manual_seed(5)).double()
    # A camera that turns back and forth: the offset shows only as the disagreement of views turned
    # against each other (a translation h of it moves a point by about h times the angle between two views).
    k = torch.arange(frames, dtype=torch.float64)
    tangents = torch.stack((0.12 * torch.cos(k / 3), 0.3 * torch.sin(k / 2), 0.05 * torch.sin(k / 4), 0.02 * k, 0.05 * torch.sin(k / 5), -0.01 * k), dim=-1)
    poses = start @ se3_exp(tangents)
    images = torch.stack([world.render_image((pose @ TRUE_OFFSET).float(), COLOUR) for pose in poses]).float()
    depths = torch.stack([render_depth_image(world.render_surface, pose, DEPTH).depth for pose in poses]).float()
    return PosedImages(
        images=images,
        T_world_cam=poses,
        intrinsics=COLOUR,
        near=0.1,
        far=20.0,
        normalization=MapNormalization(near=0.1, far=20.0),
        names=[f"frame{k}" for k in range(frames)],
        scene_bounds=torch.tensor([[-4.0, 0.0, -4.0], [4.0, 3.0, 4.0]], dtype=torch.float64),
        depths=depths,
        depth_intrinsics=DEPTH,
    )


FINE_TEXTURE = WorldConfig(texture=TextureConfig(detail_weight=0.6, noise_cell=0.03, stripe_period=0.08))
"""Centimetre detail, as a real room has: the default world's 12 cm noise cells barely change under a few centimetres' offset."""


def pixel_shift(sequence: PosedImages, T_a: torch.Tensor, T_b: torch.Tensor) -> torch.Tensor:
    """(P,) pixel distances between the projections of every frame's depth points into colour cameras at ``T_a`` and ``T_b``."""
    shifts = []
    for frame in range(0, len(sequence), 4):
        camera = sequence.depth_poses()[frame]
        depth = sequence.depths[frame]
        rows, cols = torch.nonzero(depth > 0, as_tuple=True)
        local = camera_directions_from_pixels(torch.stack((cols, rows), dim=-1).double(), DEPTH) * depth[rows, cols, None].double()
        points = local @ camera[:3, :3].T + camera[:3, 3]
        pixels = [project_points((camera @ T)[None], torch.cat((points, torch.ones_like(points[:, :1])), dim=-1), COLOUR)[0][0] for T in (T_a, T_b)]
        shifts.append((pixels[0] - pixels[1]).norm(dim=-1))
    return torch.cat(shifts)
