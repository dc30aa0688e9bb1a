"""A COLMAP reconstruction as locnerf's posed images: undistorted, downscaled images, metric gravity-aligned poses.

COLMAP poses map world to camera (``cam_from_world``, OpenCV camera axes) and its camera models put
pixel centres at half-integers; locnerf keeps camera-to-world poses with OpenGL axes and pixel
centres at integers (``c - 0.5``). Images are undistorted with OpenCV (the COLMAP models read here,
SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV, are OpenCV's radial-tangential model with
some coefficients zero) before they are downscaled.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from locnerf.data.image_files import read_rgb, stack_same_size
from locnerf.data.posed_images import PosedImages
from locnerf.data.scene_bounds import DEFAULT_NEAR, points_box
from locnerf.data.seven_scenes import read_depth, scene_box
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.frames import opencv_to_opengl
from locnerf.geometry.similarity import Similarity
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sfm.capture import Capture

logger = logging.getLogger(__name__)

NEAR_FRACTION = 0.5
"""Near bound: this fraction of the 1st percentile of the SfM points' depths in the images that see them."""


def colmap_camera(camera) -> tuple[PinholeIntrinsics, np.ndarray]:
    """A pycolmap camera -> its pinhole part (pixel centres at integers) and OpenCV distortion (k1, k2, p1, p2).

    Raises:
        DatasetError: for a camera model other than SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV.
    """
    model, p = camera.model.name, [float(v) for v in camera.params]
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        distortion = {"SIMPLE_PINHOLE": [0, 0], "SIMPLE_RADIAL": [p[3], 0], "RADIAL": p[3:5]}[model] + [0.0, 0.0]
    elif model in ("PINHOLE", "OPENCV"):
        fx, fy, cx, cy = p[:4]
        distortion = p[4:8] if model == "OPENCV" else [0.0] * 4
    else:
        raise DatasetError(f"COLMAP camera model {model}: expected SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV (undistort the images first)")
    intrinsics = PinholeIntrinsics(fx=fx, fy=fy, cx=cx - 0.5, cy=cy - 0.5, width=int(camera.width), height=int(camera.height))
    return intrinsics, np.asarray(distortion, dtype=np.float64)


def registered_poses(reconstruction, names: list[str]) -> dict[str, np.ndarray]:
    """Image name -> camera-to-world pose (4, 4) float64, OpenCV axes, SfM frame, for the posed images among ``names`` (in their order)."""
    by_name = {image.name: image for image in reconstruction.images.values() if image.has_pose}
    poses = {}
    for name in names:
        if name in by_name:
            pose = np.eye(4)
            pose[:3] = by_name[name].cam_from_world().inverse().matrix()
            poses[name] = pose
    return poses


def sparse_points(reconstruction) -> np.ndarray:
    """(P, 3) float64 the reconstruction's 3D points, SfM frame."""
    points = [point.xyz for point in reconstruction.points3D.values()]
    return np.asarray(points, dtype=np.float64).reshape(-1, 3)


def depth_observations(reconstruction, capture: Capture) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Image name -> (SfM depths (P,), sensor depths (P,) metres, 0 where none) of the 3D points each posed image sees.

    Each point is projected into the depth camera, taken at the colour camera's pose (the two are a few
    centimetres apart on an RGB-D sensor; a depth ratio is hardly changed by it), and read at the nearest pixel.
    """
    if capture.depth_paths is None or capture.depth_camera is None:
        return {}
    depth_of = dict(zip(capture.names, capture.depth_paths))
    camera = capture.depth_camera
    observations = {}
    for image in tqdm([i for i in reconstruction.images.values() if i.has_pose and i.name in depth_of], desc="depth scale", unit="image", leave=False):
        ids = [p.point3D_id for p in image.points2D if p.has_point3D()]
        if not ids:
            continue
        world = np.array([reconstruction.points3D[i].xyz for i in ids])
        pose = image.cam_from_world().matrix()
        local = world @ pose[:, :3].T + pose[:, 3]
        depth = read_depth(depth_of[image.name], 1)
        step = camera.width / depth.shape[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.round((camera.fx * local[:, 0] / local[:, 2] + camera.cx) / step).astype(np.int64)
            v = np.round((camera.fy * local[:, 1] / local[:, 2] + camera.cy) / step).astype(np.int64)
        inside = (local[:, 2] > 0) & (u >= 0) & (v >= 0) & (u < depth.shape[1]) & (v < depth.shape[0])
        sensor = np.zeros(len(local))
        sensor[inside] = depth[v[inside], u[inside]]
        observations[image.name] = (local[:, 2], sensor)
    return observations


def _undistorted_images(capture: Capture, names: list[str], intrinsics: PinholeIntrinsics, distortion: np.ndarray, downscale: int) -> np.ndarray:
    matrix = intrinsics.matrix().numpy()
    images = []
    for name in tqdm(names, desc="undistort", unit="image", leave=False):
        image = read_rgb(capture.image_root / name)
        if distortion.any():
            image = cv2.undistort(image, matrix, distortion, None, matrix)
        if downscale != 1:
            size = (max(1, round(intrinsics.width / downscale)), max(1, round(intrinsics.height / downscale)))
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        images.append(image)
    return stack_same_size(images, [capture.image_root / n for n in names])


def _box_of_points(points: np.ndarray, centres: np.ndarray, source: Path) -> torch.Tensor:
    """(2, 3) box of the SfM points (robust percentiles, with a margin) that also holds every camera centre."""
    box = points_box(torch.from_numpy(points), f"sparse points of {source}")
    return torch.stack((torch.minimum(box[0], torch.from_numpy(centres.min(0))), torch.maximum(box[1], torch.from_numpy(centres.max(0))))).double()


def posed_images_from_reconstruction(
    reconstruction, capture: Capture, to_map: Similarity, up: tuple[float, float, float], downscale: int = 1, use_depth: bool = True
) -> PosedImages:
    """The posed images of a reconstruction in the map frame ``to_map`` takes the SfM frame to (metric, gravity-aligned).

    Args:
        reconstruction: pycolmap.Reconstruction of ``capture``'s images (one shared camera).
        capture: the images (and depth images).
        to_map: SfM frame -> map frame.
        up: the map frame's up axis.
        downscale: integer image size divisor.
        use_depth: read the capture's depth images (in metres: a map frame not in metres gets no depth).
    """
    if len(reconstruction.cameras) != 1:
        raise DatasetError(f"reconstruction of {capture.source}: {len(reconstruction.cameras)} cameras, expected one shared by all images")
    intrinsics, distortion = colmap_camera(next(iter(reconstruction.cameras.values())))
    poses_cv = registered_poses(reconstruction, capture.names)
    names = list(poses_cv)
    positions = [capture.names.index(name) for name in names]
    images = _undistorted_images(capture, names, intrinsics, distortion, downscale)
    camera = intrinsics.scaled(images.shape[2] / intrinsics.width)
    T_world_cam = opencv_to_opengl(torch.from_numpy(to_map.poses(np.stack(list(poses_cv.values())))))
    points = to_map.points(sparse_points(reconstruction))
    depths, depth_camera = None, None
    if use_depth and capture.depth_paths is not None and capture.depth_camera is not None:
        stored = read_depth(capture.depth_paths[positions[0]], 1).shape
        ratio = round(capture.depth_camera.width / stored[1])
        depth_stride = max(1, downscale // ratio)
        depths = torch.from_numpy(np.stack([read_depth(capture.depth_paths[i], depth_stride) for i in positions]))
        depth_camera = capture.depth_camera.decimated(ratio * depth_stride)
        box = scene_box(T_world_cam, depths, depth_camera)
    else:
        box = _box_of_points(points, T_world_cam[:, :3, 3].numpy(), capture.source)
    local_depths = _point_depths(points, T_world_cam.numpy())
    near = max(1e-3, NEAR_FRACTION * float(np.percentile(local_depths, 1))) if len(local_depths) else DEFAULT_NEAR
    far = float((box[1] - box[0]).norm())
    logger.info("SfM images: %d posed, %dx%d, box %s, near %.3f far %.2f", len(names), camera.width, camera.height, box.numpy().round(2).tolist(), near, far)
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=T_world_cam,
        intrinsics=camera,
        near=near,
        far=far,
        normalization=MapNormalization(near=near, far=far, up=up),
        names=[str(Path(name).with_suffix("")) for name in names],
        scene_bounds=box,
        source=str(capture.source),
        indices=positions,
        depths=depths,
        depth_intrinsics=depth_camera,
        T_cam_depth=None if depths is None else torch.eye(4, dtype=torch.float64),
    )


def _point_depths(points: np.ndarray, T_world_cam_gl: np.ndarray, every: int = 10) -> np.ndarray:
    """Depths (along the optical axis) of every ``every``-th camera's view of the points in front of it."""
    depths = []
    for pose in T_world_cam_gl[::every]:
        local = (points - pose[:3, 3]) @ pose[:3, :3]
        z = -local[:, 2]
        depths.append(z[z > 0])
    return np.concatenate(depths) if depths else np.zeros(0)
