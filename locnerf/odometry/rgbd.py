"""Frame-to-frame visual odometry of an RGB-D camera with OpenCV's ``cv2.Odometry`` (the 3d module).

OpenCV's dense odometry (Steinbrücker et al. 2011 photometric, Newcombe/KinectFusion ICP, or both;
``OdometryType_RGB`` / ``_DEPTH`` / ``_RGB_DEPTH``) aligns each new frame to the last one that was
tracked: ``compute(src, dst)`` returns ``Rt = T_dst_src`` (OpenCV camera axes), so the camera pose
in the odometry frame is ``T_odom_cam(k) = T_odom_cam(k-1) · Rt⁻¹``. It needs the colour image on
the depth camera's pixel grid: :func:`register_colour` takes, for each depth pixel, the colour where its
point projects into the colour camera (the colour-depth baseline counted: ignoring the Kinect's 3 cm
under-read the kitchen's sideways motion by 9 %, against 3 % with it; docs/ODOMETRY.md).

A frame is a **gap**, never a made-up motion, when OpenCV reports failure (too few valid
correspondences), when the depth image holds fewer than ``min_valid_depth`` readings, or when the
motion is not finite or faster than a hand-held camera moves (``max_speed``, ``max_angular_speed``,
scaled by the time since the frame it was matched to). The frame after a gap is matched to the last
tracked frame, so the chain of poses stays one measured chain; gaps are counted by reason.

Poses leave with the library's OpenGL camera axes (x right, y up, z back), the first at identity.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.errors import LocnerfInputError
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)

OdometryKind = Literal["rgbd", "rgb", "depth"]
_TYPES = {"rgbd": cv2.OdometryType_RGB_DEPTH, "rgb": cv2.OdometryType_RGB, "depth": cv2.OdometryType_DEPTH}
_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes (its own inverse)


class RgbdOdometryConfig(BaseModel):
    """OpenCV dense RGB-D odometry and the checks that turn its failures into gaps."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: OdometryKind = Field("rgbd", description="rgbd: photometric + ICP (OdometryType_RGB_DEPTH); rgb: photometric with depth; depth: ICP on depth alone.")
    fast: bool = Field(False, description="OpenCV's FAST algorithm variant (OdometryAlgoType_FAST) instead of COMMON.")
    min_depth: float = Field(0.3, gt=0, description="Nearest depth reading used, metres (a Kinect reads from about 0.4 m).")
    max_depth: float = Field(4.0, gt=0, description="Farthest depth reading used, metres.")
    max_depth_diff: float = Field(0.07, gt=0, description="ICP: largest depth difference of a correspondence, metres.")
    min_valid_depth: float = Field(0.1, ge=0, le=1, description="Least fraction of valid depth pixels of a frame; fewer: a gap (no depth).")
    max_speed: float = Field(2.0, gt=0, description="Fastest plausible camera speed, m/s; a faster step is a gap.")
    max_angular_speed_deg: float = Field(270.0, gt=0, description="Fastest plausible turn, degrees per second; a faster step is a gap.")
    resume_after: int = Field(
        3,
        ge=1,
        description="After this many frames in a row that do not match the last tracked one (failed, non-finite or implausible), that"
        " frame becomes the new reference, at the last pose: tracking resumes from it, the motion across the gap unknown (the filter"
        " bridges it by widening its prediction noise with time), as after a kidnapping or a long blur.",
    )


@dataclass
class OdometryCounters:
    """What the odometry did: frames seen, poses produced, gaps by reason, time spent computing."""

    frames: int = 0
    poses: int = 0
    gaps: Counter[str] = field(default_factory=Counter)
    resumed: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict[str, object]:
        computed = max(1, self.frames - 1)
        return {
            "frames": self.frames,
            "poses": self.poses,
            "gaps": sum(self.gaps.values()),
            "gap_reasons": dict(self.gaps),
            "resumed": self.resumed,
            "ms_per_frame": 1000.0 * self.seconds / computed,
        }


def register_colour(
    rgb: np.ndarray, colour: PinholeIntrinsics, depth: PinholeIntrinsics, depth_m: np.ndarray | None = None, T_cam_depth: np.ndarray | None = None
) -> np.ndarray:
    """The colour image (H, W, 3) uint8 seen through the depth camera: (Hd, Wd, 3) uint8 on the depth grid.

    With ``depth_m`` (Hd, Wd) metres and ``T_cam_depth`` (4, 4) (the depth camera's pose in the colour
    camera's frame, OpenGL axes, metres), each depth pixel with a reading takes the colour where its
    point projects into the colour camera (bilinear). Without them, and at pixels without a reading,
    both cameras are taken to share one centre: pixel (u, v) takes the colour at ``c_c + f_c / f_d · (u - c_d)``
    per axis (pixel centres at integers), right for depth already aligned to the colour camera (a
    RealSense's ``aligned_depth_to_color``). A colour image finer than the depth grid is area-averaged to
    the depth's focal length first.
    """
    scale = colour.fx / depth.fx
    if scale > 1.0:
        coarser = colour.scaled(1.0 / scale)
        rgb, colour = cv2.resize(rgb, (coarser.width, coarser.height), interpolation=cv2.INTER_AREA), coarser
    u, v = np.meshgrid(np.arange(depth.width, dtype=np.float32), np.arange(depth.height, dtype=np.float32))
    map_u = np.float32(colour.cx) + np.float32(colour.fx / depth.fx) * (u - np.float32(depth.cx))
    map_v = np.float32(colour.cy) + np.float32(colour.fy / depth.fy) * (v - np.float32(depth.cy))
    if depth_m is not None and T_cam_depth is not None:
        if depth_m.shape != (depth.height, depth.width):
            raise ValueError(f"depth image {depth_m.shape}: expected {depth.height}x{depth.width} for the depth camera")
        T = (_FLIP @ np.asarray(T_cam_depth, dtype=np.float64) @ _FLIP).astype(np.float32)  # depth-camera -> colour-camera points, OpenCV axes
        z = depth_m.astype(np.float32)
        x, y = (u - np.float32(depth.cx)) / np.float32(depth.fx) * z, (v - np.float32(depth.cy)) / np.float32(depth.fy) * z
        xc, yc, zc = (T[i, 0] * x + T[i, 1] * y + T[i, 2] * z + T[i, 3] for i in range(3))
        seen = (z > 0) & (zc > 1e-3)
        safe = np.where(seen, zc, np.float32(1.0))
        map_u = np.where(seen, np.float32(colour.fx) * xc / safe + np.float32(colour.cx), map_u)
        map_v = np.where(seen, np.float32(colour.fy) * yc / safe + np.float32(colour.cy), map_v)
    return cv2.remap(rgb, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


class RgbdOdometry:
    """Streaming odometry: :meth:`step` with each new frame returns its pose, or None for a gap.

    Args:
        config: the OpenCV variant and the gap checks.
        camera: the depth camera (the grid of the images given to :meth:`step`).
    """

    def __init__(self, config: RgbdOdometryConfig, camera: PinholeIntrinsics) -> None:
        if config.min_depth >= config.max_depth:
            raise LocnerfInputError(f"odometry min_depth {config.min_depth} m, max_depth {config.max_depth} m: expected min_depth < max_depth")
        self.config = config
        self.camera = camera
        settings = cv2.OdometrySettings()
        settings.setCameraMatrix(np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]], dtype=np.float32))
        settings.setMinDepth(config.min_depth)
        settings.setMaxDepth(config.max_depth)
        settings.setMaxDepthDiff(config.max_depth_diff)
        algorithm = cv2.OdometryAlgoType_FAST if config.fast else cv2.OdometryAlgoType_COMMON
        self._odometry = cv2.Odometry(_TYPES[config.kind], settings, algorithm)
        self._reference: tuple[float, np.ndarray, np.ndarray] | None = None  # stamp, grey, depth of the last tracked frame
        self._pose_cv = np.eye(4)  # T_odom_cam of the last tracked frame, OpenCV axes
        self._unmatched = 0  # frames in a row that did not match the reference
        self.counters = OdometryCounters()

    def step(self, stamp: float, rgb: np.ndarray, depth_m: np.ndarray) -> torch.Tensor | None:
        """The camera pose ``T_odom_cam`` (4, 4) float64 (OpenGL axes) at this frame, or None (a gap).

        Args:
            stamp: seconds, increasing.
            rgb: (Hd, Wd, 3) uint8 on the depth camera's grid (see :func:`register_colour`).
            depth_m: (Hd, Wd) float32 metres, 0 where there is no reading.
        """
        if depth_m.shape != (self.camera.height, self.camera.width) or rgb.shape[:2] != depth_m.shape:
            raise ValueError(f"frame of colour {rgb.shape} and depth {depth_m.shape}: expected both {self.camera.height}x{self.camera.width}")
        self.counters.frames += 1
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        depth = np.ascontiguousarray(depth_m, dtype=np.float32)
        valid = float(np.count_nonzero((depth > self.config.min_depth) & (depth < self.config.max_depth))) / depth.size
        if valid < self.config.min_valid_depth:
            return self._gap("no_depth", f"{valid:.0%} valid depth", stamp)
        if self._reference is None:
            self._reference = (stamp, grey, depth)
            self.counters.poses += 1
            return self._pose()
        reference_stamp, reference_grey, reference_depth = self._reference
        started = time.perf_counter()
        if self.config.kind == "depth":
            ok, Rt = self._odometry.compute(reference_depth, depth)
        else:
            ok, Rt = self._odometry.compute(reference_depth, reference_grey, depth, grey)
        self.counters.seconds += time.perf_counter() - started
        unmatched = self._mismatch(ok, Rt, stamp - reference_stamp)
        if unmatched is not None:
            self._unmatched += 1
            if self._unmatched >= self.config.resume_after:  # lost: resume from this frame
                self._reference, self._unmatched = (stamp, grey, depth), 0
                self.counters.resumed += 1
                logger.info("odometry resumes at %.3f s from the last pose, after %d unmatched frames", stamp, self.config.resume_after)
            return self._gap(*unmatched, stamp)
        self._unmatched = 0
        self._pose_cv = self._pose_cv @ np.linalg.inv(Rt)
        self._reference = (stamp, grey, depth)
        self.counters.poses += 1
        return self._pose()

    def _mismatch(self, ok: bool, Rt: np.ndarray, elapsed: float) -> tuple[str, str] | None:
        """Why OpenCV's answer ``Rt`` (4, 4) over ``elapsed`` seconds is not a motion (gap reason and detail); None when it is one."""
        if not ok:
            return "failed", "OpenCV found no transformation"
        if not np.isfinite(Rt).all():
            return "non_finite", "non-finite motion"
        elapsed = max(elapsed, 1e-6)
        distance = float(np.linalg.norm(Rt[:3, 3]))
        angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(Rt[:3, :3])) - 1.0) / 2.0))))
        if distance > self.config.max_speed * elapsed or angle > self.config.max_angular_speed_deg * elapsed:
            return "implausible", f"{distance:.3f} m, {angle:.1f}° in {elapsed:.3f} s"
        return None

    def _pose(self) -> torch.Tensor:
        return torch.from_numpy(_FLIP @ self._pose_cv @ _FLIP)

    def _gap(self, reason: str, detail: str, stamp: float) -> None:
        self.counters.gaps[reason] += 1
        logger.info("odometry gap at %.3f s (%s): %s", stamp, reason, detail)
        return None
