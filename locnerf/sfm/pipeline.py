"""From a capture to posed images in a metric, gravity-aligned frame, with the record of how the frame was obtained.

:func:`posed_capture` runs (or loads from its cache) structure from motion on an image folder, a video
or an RGB-D data set, takes an existing COLMAP model or a nerfstudio ``transforms.json`` as it is,
fixes the scale and the up axis (:mod:`locnerf.sfm.metric`) and returns the images for
:func:`locnerf.train.build_map` together with the map metadata that records it all
(``metric_frame``, read back by :func:`locnerf.field.map_info.metric_frame_problem`).

The map frame: +z up; the origin at the centroid of the camera centres (or the trajectory's frame,
when a trajectory gives scale and gravity); metres when a scale source was given, else SfM units.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.data.map_lens import CAMERA_KEY, lens_record
from locnerf.data.trajectory_files import read_trajectory
from locnerf.data.transforms_json import read_nerfstudio
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.field.map_info import METRIC_FRAME_KEY
from locnerf.field.protocol import MapNormalization
from locnerf.geometry.frames import opencv_to_opengl, opengl_to_opencv
from locnerf.geometry.similarity import Similarity
from locnerf.sfm.alignment import FRAMES_KEY
from locnerf.sfm.capture import Capture, capture_kind, model_folder, read_capture
from locnerf.sfm.depth_camera import capture_depth_views, with_calibrated_depth_camera, with_photometric_depth_camera
from locnerf.sfm.forward_facing import forward_facing_frame, image_depth_bounds
from locnerf.sfm.metric import (
    ScaleEstimate,
    agreed_scale,
    depth_ratios,
    fit_to_trajectory,
    level_camera_up,
    rotation_to_z_up,
    scale_from_depth,
    scale_from_known_distance,
)
from locnerf.sfm.posed import colmap_camera, depth_observations, posed_images_from_reconstruction, registered_poses
from locnerf.sfm.reconstruct import SfmConfig, run_sfm
from locnerf.sfm.video import VideoSelection

logger = logging.getLogger(__name__)

MAP_UP = (0.0, 0.0, 1.0)
DEFAULT_LLFF_DOWNSCALE = 8


class MetricOptions(BaseModel):
    """Where the map's scale and up axis come from (see :mod:`locnerf.sfm.metric`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    scale: float | None = Field(None, gt=0, description="Metres per SfM unit, given by the user.")
    known_distance: tuple[str, str, float] | None = Field(
        None, description="Two frames (name, stem or capture position) and their camera centres' distance in metres."
    )
    up: tuple[float, float, float] | None = Field(
        None, description="Up direction in the first posed image's camera frame (OpenCV axes: 0 -1 0 for a level camera)."
    )
    trajectory: str | None = Field(None, description="Odometry/VIO trajectory recorded with the capture (TUM or EuRoC file, metres, gravity along -z).")
    depth: bool = Field(True, description="Take the scale from the capture's depth images when it has any.")


def _frame_lookup(names: list[str]) -> dict[str, str]:
    """Every way to name a posed frame (name, name without suffix, file stem, capture position) -> its name."""
    lookup = {}
    for position, name in enumerate(names):
        for key in (name, str(Path(name).with_suffix("")), Path(name).stem, Path(name).name.split(".")[0], str(position)):
            lookup.setdefault(key, name)
    return lookup


def metric_frame(
    poses_cv: dict[str, np.ndarray], stamps: dict[str, float] | None, depth_obs: dict, options: MetricOptions
) -> tuple[Similarity, dict[str, Any]]:
    """The SfM -> map similarity and its record.

    Args:
        poses_cv: posed image name -> camera-to-world (4, 4), OpenCV axes, SfM frame (capture order).
        stamps: image name -> seconds (for a trajectory), or None.
        depth_obs: :func:`locnerf.sfm.posed.depth_observations` (empty without depth images).
    Raises:
        LocnerfInputError / DatasetError: scale sources that disagree, a frame or trajectory that cannot be used.
    """
    names = list(poses_cv)
    centres = np.stack([poses_cv[n][:3, 3] for n in names])
    estimates: list[ScaleEstimate] = []
    if options.scale is not None:
        estimates.append(ScaleEstimate(options.scale, "user"))
    if options.known_distance is not None:
        lookup = _frame_lookup(names)
        first, second, metres = options.known_distance
        centre_of = {key: poses_cv[name][:3, 3] for key, name in lookup.items()}
        estimates.append(scale_from_known_distance(centre_of, str(first), str(second), float(metres)))
    trajectory = None
    if options.trajectory is not None:
        if stamps is None:
            raise LocnerfInputError(
                f"--trajectory {options.trajectory}: the capture's images carry no time stamps (a video, 7-Scenes frames or numeric file names do)"
            )
        trajectory, detail = fit_to_trajectory(centres, np.array([stamps[n] for n in names]), read_trajectory(options.trajectory))
        estimates.append(ScaleEstimate(trajectory.scale, "trajectory", detail))
    if options.depth and depth_obs:
        estimates.append(scale_from_depth(depth_ratios(depth_obs)))
    chosen = agreed_scale(estimates)
    scale = chosen.value if chosen is not None else 1.0
    if trajectory is not None:
        rotation = trajectory.rotation
        translation = trajectory.translation + (trajectory.scale - scale) * rotation @ centres.mean(0)
        gravity = {"source": "trajectory", "up_sfm": (rotation.T @ np.array(MAP_UP)).tolist()}
    else:
        if options.up is not None:
            up = np.asarray(options.up, dtype=np.float64)
            if np.linalg.norm(up) < 1e-9:
                raise LocnerfInputError(f"--up {options.up}: expected a non-zero direction")
            up_sfm = poses_cv[names[0]][:3, :3] @ (up / np.linalg.norm(up))
            gravity = {"source": "user", "up_camera": list(options.up), "frame": names[0]}
        else:
            up_sfm, source = level_camera_up(np.stack(list(poses_cv.values())))
            gravity = {"source": source}
        gravity["up_sfm"] = up_sfm.tolist()
        rotation = rotation_to_z_up(up_sfm)
        translation = -scale * rotation @ centres.mean(0)
    to_map = Similarity(scale, rotation, translation)
    record = {
        "metric": chosen is not None,
        "scale": None if chosen is None else {"metres_per_sfm_unit": chosen.value, "source": chosen.source, **chosen.detail},
        "scale_sources": [{"source": e.source, "metres_per_sfm_unit": e.value} for e in estimates],
        "gravity": gravity,
        "up": list(MAP_UP),
        "sfm_to_map": {"scale": scale, "rotation": rotation.tolist(), "translation": translation.tolist()},
    }
    logger.info(
        "map frame: %s (%s), up from %s",
        f"{scale:.5f} m per SfM unit" if chosen else "not metric",
        chosen.source if chosen else "no scale source",
        gravity["source"],
    )
    return to_map, record


def _transforms_as_is(path: Path, downscale: int | None, options: MetricOptions):
    """A nerfstudio transforms.json, its poses taken as they are and brought into the map frame."""
    images = read_nerfstudio(path, downscale=downscale or 1, split="all")
    poses_cv = dict(zip(images.names, opengl_to_opencv(images.T_world_cam.double()).numpy()))
    to_map, record = metric_frame(poses_cv, None, {}, options)
    poses = opencv_to_opengl(torch.from_numpy(to_map.poses(np.stack(list(poses_cv.values())))))
    corners = torch.cartesian_prod(*images.scene_bounds.double().T).numpy()
    moved = to_map.points(corners)
    box = torch.from_numpy(np.stack((moved.min(0), moved.max(0))))
    near, far = images.near * to_map.scale, images.far * to_map.scale
    normalization = MapNormalization(near=near, far=far, up=MAP_UP)
    sfm_record = {"kind": "transforms", "path": str(path), FRAMES_KEY: images.names}
    return replace(images, T_world_cam=poses, scene_bounds=box, near=near, far=far, normalization=normalization), sfm_record, record


DEPTH_CAMERA_PLACEMENTS = ("colour", "points", "photometric")
"""Where :func:`posed_capture` puts an RGB-D capture's depth camera (``map build --sfm --depth-camera``)."""


def posed_capture(
    path: str | Path,
    cache_folder: Path,
    options: MetricOptions = MetricOptions(),
    sfm: SfmConfig = SfmConfig(),
    downscale: int | None = None,
    stride: int = 1,
    split: str = "train",
    video: VideoSelection | None = None,
    depth_camera: str = "colour",
):
    """Posed images of a capture in the map frame, and map metadata (``sfm`` and ``metric_frame``).

    Args:
        path: image folder, video, RGB-D data set (pose files not read), COLMAP model folder or transforms.json.
        cache_folder: where SfM results (and a video's frames) are kept between runs.
        downscale: image size divisor of the map (default 4 for RGB-D data, else 1); an LLFF capture's images are
            ``images_<downscale>/``'s (default 8), and its map is forward-facing (NDC rays, :mod:`locnerf.sfm.forward_facing`).
        stride, split: which images of an image folder or RGB-D data set are posed.
        depth_camera: where an RGB-D capture's depth camera is (:data:`DEPTH_CAMERA_PLACEMENTS`): ``colour``, at the colour
            camera; ``points``, from the SfM points against the depth images; ``photometric``, by the grey values of
            depth points across the colour images (:mod:`locnerf.sfm.depth_camera`; docs/MAPS.md).

    Returns:
        (PosedImages, metadata dict).
    Raises:
        DatasetError: an unknown ``depth_camera``, besides the readers' and SfM's reasons.
    """
    if depth_camera not in DEPTH_CAMERA_PLACEMENTS:
        raise DatasetError(f"depth camera placement {depth_camera!r}: expected one of {', '.join(DEPTH_CAMERA_PLACEMENTS)}")
    path = Path(path)
    kind = capture_kind(path)
    if kind == "transforms":
        images, sfm_record, record = _transforms_as_is(path, downscale, options)
        return images, {"sfm": sfm_record, METRIC_FRAME_KEY: record}
    if kind == "colmap":
        import pycolmap

        folder = model_folder(path)
        reconstruction = pycolmap.Reconstruction(folder)
        root = path / "images" if (path / "images").is_dir() else path.parent / "images"
        names = sorted(image.name for image in reconstruction.images.values())
        capture = Capture("images", path, root, names)
        sfm_record = {"kind": "colmap", "model": str(folder)}
    else:
        capture = read_capture(path, cache_folder, stride=stride, split=split, video=video, llff_downscale=downscale or DEFAULT_LLFF_DOWNSCALE)
        result = run_sfm(capture, cache_folder / "sfm", sfm)
        reconstruction = result.reconstruction
        sfm_record = {
            "kind": capture.kind,
            "model": str(result.model_folder),
            "images": len(capture),
            "posed": len(capture) - len(result.unregistered),
            "unregistered": result.unregistered,
            "seconds": round(result.seconds, 1),
            "cached": result.cached,
            "config": sfm.model_dump(mode="json"),
        }
    poses_cv = registered_poses(reconstruction, capture.names)
    if not poses_cv:
        raise DatasetError(f"capture {path}: the reconstruction poses none of its images")
    stamps = dict(zip(capture.names, capture.stamps)) if capture.stamps is not None else None
    depth_obs = depth_observations(reconstruction, capture) if options.depth else {}
    to_map, record = metric_frame(poses_cv, stamps, depth_obs, options)
    scale_down = 1 if capture.kind == "llff" else downscale or (4 if capture.depth_paths is not None else 1)
    images = posed_images_from_reconstruction(reconstruction, capture, to_map, MAP_UP, scale_down, use_depth=record["metric"])
    if capture.kind == "llff":
        images, sfm_record["forward_facing"] = forward_facing_frame(images, image_depth_bounds(reconstruction, list(poses_cv), to_map.scale))
    placed = {}
    if depth_camera == "points":
        images, placed = with_calibrated_depth_camera(images, capture_depth_views(reconstruction, capture, to_map.scale))
    elif depth_camera == "photometric":
        images, placed = with_photometric_depth_camera(images)
    sfm_record[FRAMES_KEY] = images.names
    sfm_record[CAMERA_KEY] = lens_record(*colmap_camera(next(iter(reconstruction.cameras.values()))))
    return images, {"sfm": sfm_record, METRIC_FRAME_KEY: record, **placed}
