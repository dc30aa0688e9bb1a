"""``transforms.json`` data sets: NeRF-synthetic (``transforms_<split>.json``) and nerfstudio.

Both store OpenGL camera-to-world matrices per frame (``transform_matrix``). NeRF-synthetic gives
one ``camera_angle_x`` and RGBA images of an object inside the cube [-1.5, 1.5]³; nerfstudio gives
``fl_x, fl_y, cx, cy, w, h`` at the top level or per frame, and optionally OpenCV distortion
``k1 k2 k3 p1 p2``, which is removed here so that every image is an ideal pinhole image.

Cameras: only nerfstudio's perspective ``camera_model`` values (:data:`PERSPECTIVE_MODELS`, and no
``camera_model``, which nerfstudio reads as ``OPENCV``) are read; a fisheye, equirectangular or other
projection is refused, as is a non-zero ``k4`` (nerfstudio's r⁸ radial term, which OpenCV's model
lacks). ``cx, cy`` are in the corner convention (the top-left pixel's centre at (0.5, 0.5), so
``cx = w/2`` for a centred camera; nerfstudio and instant-ngp cast rays through ``pixel + 0.5``) and
become the library's pixel-centre convention here (:mod:`locnerf.render.camera`): ``cx - 0.5``.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from locnerf.data.image_files import read_rgb, resolve_image_path, stack_same_size
from locnerf.data.posed_images import PosedImages
from locnerf.data.scene_bounds import transforms_scene_box
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

SYNTHETIC_BOUNDS = 1.5
SYNTHETIC_NEAR, SYNTHETIC_FAR = 2.0, 6.0
HOLDOUT_EVERY = 8
BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
"""nerfstudio ``camera_model`` values of a pinhole camera with (at most) OpenCV radial-tangential distortion."""


def _load_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        content = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise DatasetError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(content, dict) or not isinstance(content.get("frames"), list) or not content["frames"]:
        raise DatasetError(f"{path}: expected an object with a non-empty 'frames' list")
    return content


def _frame_pose(frame: dict[str, Any], path: Path, position: int) -> np.ndarray:
    matrix = np.asarray(frame.get("transform_matrix"), dtype=np.float64)
    if matrix.shape != (4, 4):
        raise DatasetError(f"{path}: frame {position} transform_matrix of shape {matrix.shape}, expected (4, 4)")
    if not np.isfinite(matrix).all():
        raise DatasetError(f"{path}: frame {position} ({frame.get('file_path')}) has a NaN or infinite pose")
    return matrix


def _background(background: str | tuple[float, float, float]) -> tuple[float, float, float]:
    if isinstance(background, str):
        if background not in BACKGROUNDS:
            raise DatasetError(f"background {background!r}: expected one of {sorted(BACKGROUNDS)} or an RGB triple")
        return BACKGROUNDS[background]
    return tuple(float(c) for c in background)  # type: ignore[return-value]


def read_nerf_synthetic(
    folder: str | Path,
    split: str = "train",
    background: str | tuple[float, float, float] = "white",
    downscale: int = 1,
    skip_missing: bool = False,
) -> PosedImages:
    """Read one split of a NeRF-synthetic scene.

    Args:
        folder: holds ``transforms_<split>.json`` and the images it names.
        split: ``train``, ``val`` or ``test``.
        background: colour the RGBA images are composited on ("white", "black" or RGB in [0, 1]).
        downscale: integer image size divisor (area resize).
        skip_missing: leave out frames whose image file is absent (logged) instead of refusing.
    """
    folder = Path(folder)
    path = folder / f"transforms_{split}.json"
    content = _load_json(path)
    if "camera_angle_x" not in content:
        raise DatasetError(f"{path}: no camera_angle_x (the horizontal field of view) given")
    frames = _present_frames(content["frames"], folder, path, skip_missing)
    rgb = _background(background)
    paths = [resolve_image_path(folder / frame["file_path"]) for frame in frames]
    images = stack_same_size([read_rgb(p, downscale, rgb) for p in paths], paths)
    height, width = images.shape[1:3]
    intrinsics = PinholeIntrinsics.from_fov(width, height, float(content["camera_angle_x"]))
    poses = np.stack([_frame_pose(frame, path, i) for i, frame in enumerate(frames)])
    # Blender scenes are z-up: the yaw axis of global localization is the world z axis.
    normalization = MapNormalization(near=SYNTHETIC_NEAR, far=SYNTHETIC_FAR, up=(0.0, 0.0, 1.0))
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=torch.from_numpy(poses),
        intrinsics=intrinsics,
        near=SYNTHETIC_NEAR,
        far=SYNTHETIC_FAR,
        normalization=normalization,
        names=[p.stem for p in paths],
        scene_bounds=torch.tensor([[-SYNTHETIC_BOUNDS] * 3, [SYNTHETIC_BOUNDS] * 3], dtype=torch.float64),
        white_background=rgb == (1.0, 1.0, 1.0),
        source=str(folder),
    )


def _present_frames(frames: list[dict[str, Any]], folder: Path, path: Path, skip_missing: bool) -> list[dict[str, Any]]:
    if not skip_missing:
        return frames
    present = []
    for frame in frames:
        try:
            resolve_image_path(folder / frame["file_path"])
            present.append(frame)
        except FileNotFoundError:
            continue
    if not present:
        raise FileNotFoundError(f"{path}: none of the {len(frames)} images it names exists")
    if len(present) < len(frames):
        logger.warning("%s: %d of %d images are missing and left out", path, len(frames) - len(present), len(frames))
    return present


def _frame_camera(content: dict[str, Any], frame: dict[str, Any], path: Path) -> tuple[PinholeIntrinsics, np.ndarray]:
    """Intrinsics (pixel-centre convention) and OpenCV distortion (k1, k2, p1, p2, k3) of one frame
    (frame keys override shared ones).

    Raises:
        DatasetError: naming the file and frame, for a camera that is not a perspective one, a non-zero
            ``k4``, or missing size or focal length.
    """

    def value(key: str) -> Any:
        return frame.get(key, content.get(key))

    model = value("camera_model")
    if model is not None and str(model).upper() not in PERSPECTIVE_MODELS:
        raise DatasetError(
            f"{path}: frame {frame.get('file_path')} has camera_model {model!r}: expected a perspective camera, one of {PERSPECTIVE_MODELS} "
            "(fisheye, equirectangular and other projections are not read; undistort such images to a pinhole camera first)"
        )
    if float(value("k4") or 0.0):
        raise DatasetError(
            f"{path}: frame {frame.get('file_path')} has k4={value('k4')}: expected none or 0 (nerfstudio's r^8 radial term has no OpenCV equivalent)"
        )

    width, height = value("w"), value("h")
    if width is None or height is None:
        raise DatasetError(f"{path}: frame {frame.get('file_path')} has no image size w, h")
    if value("fl_x") is not None:
        fx = float(value("fl_x"))
        fy = float(value("fl_y") if value("fl_y") is not None else fx)
    elif value("camera_angle_x") is not None:
        fx = fy = 0.5 * float(width) / math.tan(0.5 * float(value("camera_angle_x")))
    else:
        raise DatasetError(f"{path}: frame {frame.get('file_path')} has no intrinsics (fl_x/fl_y or camera_angle_x)")
    # Corner convention in the file (centred: w/2), pixel centres at integers here.
    cx = float(value("cx") if value("cx") is not None else width / 2.0) - 0.5
    cy = float(value("cy") if value("cy") is not None else height / 2.0) - 0.5
    intrinsics = PinholeIntrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=int(width), height=int(height))
    distortion = np.array([float(value(k) or 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
    return intrinsics, distortion


def _undistort(image: np.ndarray, intrinsics: PinholeIntrinsics, distortion: np.ndarray) -> np.ndarray:
    """The ideal pinhole image with the same intrinsics (OpenCV radial-tangential model, coefficients (k1, k2, p1, p2, k3))."""
    if not distortion.any():
        return image
    matrix = intrinsics.matrix().numpy()
    return cv2.undistort(image, matrix, distortion, None, matrix)


def read_nerfstudio(
    path: str | Path, downscale: int = 1, split: str = "all", holdout_every: int = HOLDOUT_EVERY, background: str | tuple[float, float, float] = "white"
) -> PosedImages:
    """Read a nerfstudio ``transforms.json`` (or the folder holding it).

    All frames must share one camera after undistortion and downscaling. The scene bounds come
    from the file's ``aabb``, sparse points, depth images, ``aabb_scale`` or ``near``/``far``
    (:func:`locnerf.data.scene_bounds.transforms_scene_box`); a file with none of them is refused.

    Args:
        path: ``transforms.json`` or its folder.
        downscale: integer image size divisor.
        split: ``all``, ``train`` or ``test`` (every ``holdout_every``-th frame held out).
        background: colour for RGBA images.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "transforms.json"
    content = _load_json(path)
    frames = content["frames"]
    positions = _split(len(frames), split, holdout_every)
    cameras = [_frame_camera(content, frames[i], path) for i in positions]
    first = cameras[0][0]
    for (camera, _), i in zip(cameras, positions):
        if camera != first:
            raise DatasetError(f"{path}: frame {frames[i].get('file_path')} has camera {camera}, expected one shared camera {first}")
    paths = [resolve_image_path(path.parent / frames[i]["file_path"]) for i in positions]
    rgb = _background(background)
    raw = [read_rgb(p, 1.0, rgb) for p in paths]
    for image, image_path in zip(raw, paths):
        if image.shape[:2] != (first.height, first.width):
            raise DatasetError(f"image {image_path} is {image.shape[1]}x{image.shape[0]}: expected {first.width}x{first.height} from {path}")
    undistorted = [_undistort(image, camera, distortion) for image, (camera, distortion) in zip(raw, cameras)]
    if downscale != 1:
        size = (max(1, round(first.width / downscale)), max(1, round(first.height / downscale)))
        undistorted = [cv2.resize(image, size, interpolation=cv2.INTER_AREA) for image in undistorted]
    images = stack_same_size(undistorted, paths)
    intrinsics = first.scaled(images.shape[2] / first.width)
    poses = np.stack([_frame_pose(frames[i], path, i) for i in positions])
    bounds, near, far = transforms_scene_box(content, path, [frames[i] for i in positions], poses, first)
    normalization = MapNormalization(near=near, far=far)
    return PosedImages(
        images=torch.from_numpy(images),
        T_world_cam=torch.from_numpy(poses),
        intrinsics=intrinsics,
        near=near,
        far=far,
        normalization=normalization,
        names=[p.stem for p in paths],
        scene_bounds=bounds,
        white_background=rgb == (1.0, 1.0, 1.0),
        source=str(path),
        indices=positions,
    )


def _split(count: int, split: str, holdout_every: int) -> list[int]:
    held_out = set(range(0, count, holdout_every))
    if split == "all":
        return list(range(count))
    if split == "test":
        return sorted(held_out)
    if split == "train":
        return [i for i in range(count) if i not in held_out]
    raise DatasetError(f"split {split!r}: expected all, train or test for a nerfstudio transforms.json")
