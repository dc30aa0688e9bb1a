"""The box a map's grid covers, from what a data set says about its scene.

A grid map holds its scene in one axis-aligned box; rays march only inside it, so a surface
outside the box cannot be explained by the map. Object captures (NeRF-synthetic) state the box;
rooms and walls must be bounded by what the cameras saw. The helpers here bound a scene by
points (back-projected depth, a sparse point cloud, robust per-axis percentiles) or by the union of
camera frusta between a near and a far depth, and :func:`transforms_scene_box` picks among them
for a ``transforms.json`` (see its docstring for the keys it reads and their order).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from locnerf.errors import DatasetError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import camera_directions_from_pixels

logger = logging.getLogger(__name__)

BOX_PERCENTILES = (0.5, 99.5)
"""Points outside these per-axis percentiles (sensor or triangulation outliers) do not widen a box."""
BOUNDS_FRAMES, BOUNDS_PIXELS = 150, 2000
"""Frames (evenly spread) and pixels per frame (about) back-projected for a scene box."""
BOX_MARGIN_FRACTION = 0.05
"""A box from points is grown by this fraction of its longest edge on every side."""
MIN_BOX_POINTS = 8
"""Fewest points a box is taken from."""
DEFAULT_NEAR = 0.05
"""Near bound of rays (map units) where the data set gives none."""
INTEGER_DEPTH_SCALE = 1e-3
"""Map units per step of an integer depth image where ``integer_depth_scale`` is absent (millimetres, nerfstudio's default)."""
NGP_SCALE, NGP_OFFSET = 0.33, 0.5
"""instant-ngp's defaults mapping a transforms.json frame into its unit cube: ``ngp = scale · x + offset``."""
PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
TO_ADD = (
    "add one of: 'ply_file_path' (a sparse point cloud in the frame of the poses, as ns-process-data writes), "
    "'depth_file_path' per frame (depth images), 'aabb' [[x0, y0, z0], [x1, y1, z1]] (the scene box), "
    "'aabb_scale' (instant-ngp), or 'near' and 'far' (the depth range the cameras see, in the poses' units)"
)


def depth_points(depths: torch.Tensor, T_world_cam: torch.Tensor, camera: PinholeIntrinsics) -> torch.Tensor:
    """(P, 3) world points of the valid pixels of depth images (K, H, W) seen from poses (K, 4, 4) (OpenGL axes).

    Directions have camera z = -1, so a pixel's point is its direction times its depth. The pixel
    grid is the images' own (H, W); ``camera`` gives the focal lengths and principal point.
    """
    height, width = depths.shape[1:]
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64), indexing="ij")
    directions = camera_directions_from_pixels(torch.stack((u, v), dim=-1), camera)  # (H, W, 3)
    points = []
    for depth, pose in zip(depths.double(), T_world_cam.double()):
        valid = depth > 0
        local = directions[valid] * depth[valid][:, None]
        points.append(local @ pose[:3, :3].T + pose[:3, 3])
    return torch.cat(points) if points else torch.zeros(0, 3, dtype=torch.float64)


def bounds_pixel_step(width: int, height: int) -> int:
    """Pixel stride that leaves about ``BOUNDS_PIXELS`` pixels of a width × height image."""
    return max(1, round((width * height / BOUNDS_PIXELS) ** 0.5))


def percentile_box(points: torch.Tensor) -> torch.Tensor:
    """(2, 3) float64 per-axis ``BOX_PERCENTILES`` of points (P, 3), P >= 1 (at most about a million of them used, evenly strided)."""
    percentiles = torch.tensor(BOX_PERCENTILES, dtype=torch.float64) / 100.0
    return torch.quantile(points.double()[:: max(1, len(points) // 1_000_000)], percentiles, dim=0)


def points_box(points: torch.Tensor, what: str) -> torch.Tensor:
    """(2, 3) float64 box of points (P, 3) (robust percentiles), grown by ``BOX_MARGIN_FRACTION`` of its longest edge.

    Raises:
        DatasetError: naming ``what`` when fewer than ``MIN_BOX_POINTS`` finite points are given.
    """
    points = points[torch.isfinite(points).all(dim=1)]
    if len(points) < MIN_BOX_POINTS:
        raise DatasetError(f"{what}: {len(points)} finite points, expected at least {MIN_BOX_POINTS} to bound the scene")
    box = percentile_box(points)
    margin = BOX_MARGIN_FRACTION * float((box[1] - box[0]).max())
    return torch.stack((box[0] - margin, box[1] + margin))


def frustum_box(T_world_cam: torch.Tensor, camera: PinholeIntrinsics, near: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """(2, 3) float64 box of the union of the camera frusta between depths ``near`` and ``far`` (K,) (along the optical axis).

    A frustum is the convex hull of its image corners at the near and far depth, so the box of
    those 8 points per camera holds it. ``T_world_cam``: (K, 4, 4), OpenGL camera axes.
    """
    left, top, right, bottom = -0.5, -0.5, camera.width - 0.5, camera.height - 0.5
    corners = torch.tensor([[left, top], [right, top], [left, bottom], [right, bottom]], dtype=torch.float64)
    directions = camera_directions_from_pixels(corners, camera)  # (4, 3), z = -1
    depths = torch.stack((near, far), dim=1).double()  # (K, 2)
    local = directions[None, None] * depths[:, :, None, None]  # (K, 2, 4, 3)
    rotation, centre = T_world_cam[:, :3, :3].double(), T_world_cam[:, :3, 3].double()
    world = torch.einsum("kij,knpj->knpi", rotation, local) + centre[:, None, None]
    points = world.reshape(-1, 3)
    return torch.stack((points.amin(0), points.amax(0)))


def read_ply_points(path: Path) -> torch.Tensor:
    """(P, 3) float64 x, y, z of the ``vertex`` element of a PLY file (ASCII or binary; the vertex element must come first).

    Raises:
        FileNotFoundError: no such file.
        DatasetError: naming the file and what is malformed.
    """
    if not path.is_file():
        raise FileNotFoundError(f"point cloud {path}: no such file")
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise DatasetError(f"point cloud {path}: not a PLY file (no 'ply' ... 'end_header' header)")
    lines = [line.split() for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]]
    body = data[data.index(b"\n", end) + 1 :]
    formats = [line[1] for line in lines if len(line) > 1 and line[0] == "format"]
    elements = [line for line in lines if line and line[0] == "element"]
    if not formats or formats[0] not in PLY_FORMATS or not elements or elements[0][1:2] != ["vertex"] or not elements[0][-1].isdigit():
        raise DatasetError(f"point cloud {path}: expected a PLY of format {sorted(PLY_FORMATS)} whose first element is 'vertex' with a count")
    count = int(elements[0][-1])
    properties = []
    for line in lines[lines.index(elements[0]) + 1 :]:
        if line and line[0] == "element":
            break
        if len(line) > 2 and line[0] == "property":
            if line[1] == "list" or line[1] not in PLY_TYPES:
                raise DatasetError(f"point cloud {path}: vertex property {' '.join(line[1:])} of a type this reader does not know")
            properties.append((line[2], PLY_FORMATS[formats[0]] + PLY_TYPES[line[1]]))
    names = [name for name, _ in properties]
    if not {"x", "y", "z"} <= set(names):
        raise DatasetError(f"point cloud {path}: vertex properties {names}, expected x, y and z")
    try:
        if formats[0] == "ascii":
            table = np.loadtxt(body.decode("ascii").splitlines()[:count], dtype=np.float64, ndmin=2)
            xyz = table[:, [names.index(axis) for axis in "xyz"]]
        else:
            table = np.frombuffer(body, dtype=np.dtype(properties), count=count)
            xyz = np.stack([table[axis].astype(np.float64) for axis in "xyz"], axis=1)
    except (ValueError, IndexError, UnicodeDecodeError) as error:
        raise DatasetError(f"point cloud {path}: {count} vertices announced, body unreadable ({error})") from None
    return torch.from_numpy(np.ascontiguousarray(xyz))


def _read_depth_image(path: Path, integer_scale: float) -> np.ndarray:
    """(H, W) float64 depth in the poses' units, 0 where invalid: integer images times ``integer_scale``, float images as stored (``.npy`` or image files)."""
    if not path.is_file():
        raise FileNotFoundError(f"depth image {path}: no such file")
    raw = np.load(path) if path.suffix == ".npy" else cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 2:
        raise DatasetError(f"depth image {path}: cannot be read as a single-channel depth image")
    depth = raw.astype(np.float64) * (integer_scale if np.issubdtype(raw.dtype, np.integer) else 1.0)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return depth


def _depth_box(frames: list[dict[str, Any]], poses: np.ndarray, camera: PinholeIntrinsics, content: dict[str, Any], path: Path) -> torch.Tensor | None:
    """Box of the back-projected depth of up to ``BOUNDS_FRAMES`` frames that name a depth image; None when none does."""
    with_depth = [i for i, frame in enumerate(frames) if frame.get("depth_file_path", frame.get("depth_path"))]
    if not with_depth:
        return None
    integer_scale = float(content.get("integer_depth_scale", INTEGER_DEPTH_SCALE))
    points = []
    for i in with_depth[:: max(1, len(with_depth) // BOUNDS_FRAMES)]:
        depth_path = path.parent / frames[i].get("depth_file_path", frames[i].get("depth_path"))
        depth = _read_depth_image(depth_path, integer_scale)
        height, width = depth.shape
        if abs(height * camera.width - width * camera.height) > max(camera.width, camera.height):
            raise DatasetError(f"depth image {depth_path}: {width}x{height}, expected the aspect of the {camera.width}x{camera.height} images")
        step = bounds_pixel_step(width, height)
        sampled = torch.from_numpy(np.ascontiguousarray(depth[::step, ::step]))[None]
        points.append(depth_points(sampled, torch.from_numpy(poses[i : i + 1]), camera.scaled(width / camera.width).decimated(step)))
    return points_box(torch.cat(points), f"{path}: the depth images")


def _given_box(value: Any, key: str, path: Path) -> torch.Tensor:
    """(2, 3) float64 box from a ``[[x0, y0, z0], [x1, y1, z1]]`` entry."""
    try:
        box = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError):
        box = torch.zeros(0)
    if box.shape != (2, 3) or not torch.isfinite(box).all() or not bool((box[1] > box[0]).all()):
        raise DatasetError(f"{path}: {key} {value!r}, expected [[x0, y0, z0], [x1, y1, z1]] with finite numbers and x0 < x1, y0 < y1, z0 < z1")
    return box


def _ngp_box(content: dict[str, Any], path: Path) -> torch.Tensor:
    """instant-ngp's scene box in the transforms.json frame: the cube of edge ``aabb_scale`` around 0.5 in its space,
    mapped back through ``ngp = scale · x + offset`` (``scale`` 0.33, ``offset`` 0.5 unless given)."""
    values = (content["aabb_scale"], content.get("scale", NGP_SCALE), content.get("offset", NGP_OFFSET))
    try:
        aabb_scale, scale, offset = float(values[0]), float(values[1]), torch.tensor(values[2], dtype=torch.float64).expand(3)
    except (TypeError, ValueError, RuntimeError):
        aabb_scale, scale, offset = float("nan"), float("nan"), torch.zeros(3)
    if not (np.isfinite(aabb_scale) and aabb_scale > 0 and np.isfinite(scale) and scale > 0 and torch.isfinite(offset).all()):
        raise DatasetError(
            f"{path}: aabb_scale, scale, offset {values}: expected positive finite aabb_scale and scale, and a finite offset (one number or three)"
        )
    return torch.stack(((0.5 - aabb_scale / 2 - offset) / scale, (0.5 + aabb_scale / 2 - offset) / scale))


def _near_far(frames: list[dict[str, Any]], content: dict[str, Any], path: Path) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Per-frame (K,) near and far depths (frame entries override shared ones); None when not every frame has both."""
    pairs = [(frame.get("near", content.get("near")), frame.get("far", content.get("far"))) for frame in frames]
    if any(near is None or far is None for near, far in pairs):
        return None
    try:
        near, far = torch.tensor(pairs, dtype=torch.float64).T
    except (TypeError, ValueError):
        near, far = torch.full((1,), float("nan")), torch.full((1,), float("nan"))
    if not (torch.isfinite(near).all() and torch.isfinite(far).all() and bool((near >= 0).all()) and bool((far > near).all())):
        raise DatasetError(f"{path}: near, far {pairs[0]} (first frame): expected numbers with 0 <= near < far for every frame")
    return near, far


def transforms_scene_box(
    content: dict[str, Any], path: Path, frames: list[dict[str, Any]], poses: np.ndarray, camera: PinholeIntrinsics
) -> tuple[torch.Tensor, float, float]:
    """(2, 3) float64 scene box, near and far of a ``transforms.json``'s ``frames`` (the ones read).

    The first of these the file offers gives the box:

    1. ``aabb`` ``[[x0, y0, z0], [x1, y1, z1]]`` (instant-ngp's key): the box as written;
    2. ``ply_file_path``: the sparse points (nerfstudio's ``sparse_pc.ply``, in the poses' frame);
    3. ``depth_file_path`` (nerfstudio) or ``depth_path`` (instant-ngp) per frame: the back-projected
       depth (integer images times ``integer_depth_scale``, default 1e-3: millimetres);
    4. ``aabb_scale`` (instant-ngp, with its ``scale`` and ``offset``): instant-ngp's own scene cube;
    5. ``near`` and ``far`` (shared or per frame): the union of the camera frusta between them.

    Boxes from points are their 0.5–99.5 percentiles per axis grown by 5 % of the longest edge.
    ``near`` and ``far`` are the file's where it gives them; otherwise 0.05 and the distance from
    the farthest camera to the farthest box corner.

    Args:
        content: the parsed file; path: its path (relative paths are resolved beside it).
        frames: the frames read; poses: their (K, 4, 4) OpenGL camera-to-world matrices.
        camera: their shared camera at the stored image size (depth images may be smaller).
    Raises:
        DatasetError: when none of these is there (the message lists what to add), or one is malformed.
    """
    depth_range = _near_far(frames, content, path)
    if "aabb" in content:
        box, source = _given_box(content["aabb"], "aabb", path), "aabb"
    elif content.get("ply_file_path"):
        ply = path.parent / content["ply_file_path"]
        box, source = points_box(read_ply_points(ply), str(ply)), f"the sparse points of {ply.name}"
    elif (depth := _depth_box(frames, poses, camera, content, path)) is not None:
        box, source = depth, "the depth images"
    elif "aabb_scale" in content:
        box, source = _ngp_box(content, path), f"aabb_scale {content['aabb_scale']}"
    elif depth_range is not None:
        box, source = frustum_box(torch.from_numpy(poses), camera, *depth_range), "the camera frusta between near and far"
    else:
        raise DatasetError(f"{path}: cannot bound the scene (its map's grid needs a box): {TO_ADD}")
    centres = torch.from_numpy(poses[:, :3, 3])
    corners = torch.cartesian_prod(*box.T)  # (8, 3)
    near = float(depth_range[0].min()) if depth_range is not None else DEFAULT_NEAR
    far = float(depth_range[1].max()) if depth_range is not None else float(torch.cdist(centres, corners).max())
    logger.info("%s: scene box %s from %s, near %.3g, far %.3g", path, box.numpy().round(3).tolist(), source, near, far)
    return box, near, far
