"""A small hand-held capture of the procedural world written as files: colour PNGs, and depth PNGs in the 7-Scenes layout.

The camera walks 2.4 m across the room turning ±15°, so that structure from motion has
baseline and overlap; the true poses (OpenGL camera-to-world, metres, world y up) are returned for
the tests to score against. Depth images are exact (rendered), uint16 millimetres, every second
pixel of the colour image's grid, from the colour camera itself (camera-intrinsics.txt).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import torch

from locnerf.geometry import make_pose, so3_exp
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels
from locnerf.sim.world import ProceduralWorld
from tests.data.rgbd_world import FINE_TEXTURE

CAMERA = PinholeIntrinsics.from_fov(240, 180, math.radians(70))
FRAMES = 12


def capture_poses(frames: int = FRAMES) -> torch.Tensor:
    """(K, 4, 4) float64 OpenGL camera-to-world poses: a walk from x = -1.2 to 1.2 m at 1.4 m height, looking along -z, turning ±15°."""
    poses = []
    for k in range(frames):
        fraction = k / (frames - 1)
        yaw = math.radians(15.0) * math.sin(2 * math.pi * fraction)
        pitch = math.radians(-5.0) + math.radians(4.0) * math.cos(3 * math.pi * fraction)
        rotation = so3_exp(torch.tensor([0.0, yaw, 0.0], dtype=torch.float64)) @ so3_exp(torch.tensor([pitch, 0.0, 0.0], dtype=torch.float64))
        poses.append(make_pose(rotation, torch.tensor([-1.2 + 2.4 * fraction, 1.4, 1.5 + 0.3 * math.sin(math.pi * fraction)], dtype=torch.float64)))
    return torch.stack(poses)


def _png(image: torch.Tensor) -> np.ndarray:
    return (image.clamp(0, 1).numpy()[:, :, ::-1] * 255.0 + 0.5).astype(np.uint8)


def write_world_capture(folder: Path, frames: int = FRAMES, depth: bool = True) -> torch.Tensor:
    """Write the capture to ``folder``: with ``depth``, 7-Scenes layout (``TrainSplit.txt``, ``seq-01/frame-NNNNNN.color.png``,
    ``.depth.png``, ``camera-intrinsics.txt``, no pose files); without, a plain image folder. Returns the true poses (K, 4, 4)."""
    world = ProceduralWorld(FINE_TEXTURE)
    poses = capture_poses(frames)
    images = folder / "seq-01" if depth else folder
    images.mkdir(parents=True, exist_ok=True)
    pixels = pixel_grid(CAMERA).double()
    for k, pose in enumerate(poses):
        stem = f"frame-{k:06d}" if depth else f"image{k:03d}"
        origins, directions = rays_from_poses_and_pixels(pose[None], pixels, CAMERA)
        colours, points, hit = world.render_surface(origins.reshape(-1, 3), directions.reshape(-1, 3))
        cv2.imwrite(str(images / (stem + (".color.png" if depth else ".png"))), _png(colours.reshape(CAMERA.height, CAMERA.width, 3).float()))
        if depth:
            # depth along the optical axis (-z of the OpenGL camera), every second pixel as 7-Scenes stores it
            metres = (-((points - pose[:3, 3]) @ pose[:3, 2]) * hit).reshape(CAMERA.height, CAMERA.width)[::2, ::2]
            cv2.imwrite(str(images / f"{stem}.depth.png"), (metres.numpy() * 1000.0 + 0.5).astype(np.uint16))
    if depth:
        (folder / "TrainSplit.txt").write_text("sequence1\n")
        (folder / "TestSplit.txt").write_text("sequence1\n")
        np.savetxt(folder / "camera-intrinsics.txt", CAMERA.matrix().numpy())
    return poses
