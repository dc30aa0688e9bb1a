"""The one posed-image type every dataset reader returns."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import torch

from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.render.camera import PinholeIntrinsics


@dataclass(frozen=True)
class PosedImages:
    """Images with camera-to-world poses in the map frame and one shared pinhole camera.

    Attributes:
        images: (K, H, W, 3) float32 RGB in [0, 1].
        T_world_cam: (K, 4, 4) float64 camera-to-world poses, OpenGL camera axes, map frame.
        intrinsics: the (undistorted, downscaled) camera of every image.
        near: near bound of rays in map units.
        far: far bound of rays in map units.
        normalization: how the map frame relates to the data set's frame (incl. the NDC flag).
        names: K image names (file stems), in reading order.
        scene_bounds: (2, 3) min/max corner of the region holding the scene, in the frame where
            the field lives (map frame, or NDC space when ``normalization.ndc``).
        white_background: the images were composited on white (RGBA data sets).
        source: the path the images were read from, for map metadata.
        indices: K frame numbers, unique within the data set (positions in its full frame list).
        depths: (K, Hd, Wd) float32 depth along each depth camera's optical axis in map units,
            0 where the sensor gave none; None for colour-only data sets.
        depth_intrinsics: the camera of ``depths``. The depth images are not registered to the
            colour images: each is used with its own camera.
        T_cam_depth: (4, 4) float64 the depth camera's pose in the colour camera's frame (map units),
            set once the poses were moved onto a calibrated colour camera
            (:func:`locnerf.data.colour_camera.with_colour_camera`); None: the depth camera sits at
            ``T_world_cam`` (RGB-D data sets pose the depth camera and, as read, the pose serves both).
    """

    images: torch.Tensor
    T_world_cam: torch.Tensor
    intrinsics: PinholeIntrinsics
    near: float
    far: float
    normalization: MapNormalization
    names: list[str]
    scene_bounds: torch.Tensor
    white_background: bool = False
    source: str = ""
    indices: list[int] = field(default_factory=list)
    depths: torch.Tensor | None = None
    depth_intrinsics: PinholeIntrinsics | None = None
    T_cam_depth: torch.Tensor | None = None

    def __post_init__(self) -> None:
        count = self.images.shape[0]
        expected_image = (count, self.intrinsics.height, self.intrinsics.width, 3)
        if tuple(self.images.shape) != expected_image:
            raise DatasetError(f"images of shape {tuple(self.images.shape)}: expected {expected_image} for {self.source}")
        if tuple(self.T_world_cam.shape) != (count, 4, 4):
            raise DatasetError(f"T_world_cam of shape {tuple(self.T_world_cam.shape)}: expected ({count}, 4, 4) for {self.source}")
        if len(self.names) != count:
            raise DatasetError(f"{len(self.names)} names for {count} images in {self.source}")
        if (self.depths is None) != (self.depth_intrinsics is None):
            raise DatasetError(f"depths and depth_intrinsics must be given together for {self.source}")
        if self.depths is not None and self.depth_intrinsics is not None:
            expected_depth = (count, self.depth_intrinsics.height, self.depth_intrinsics.width)
            if tuple(self.depths.shape) != expected_depth:
                raise DatasetError(f"depths of shape {tuple(self.depths.shape)}: expected {expected_depth} for {self.source}")
        if self.T_cam_depth is not None and tuple(self.T_cam_depth.shape) != (4, 4):
            raise DatasetError(f"T_cam_depth of shape {tuple(self.T_cam_depth.shape)}: expected (4, 4) for {self.source}")
        if not self.indices:
            object.__setattr__(self, "indices", list(range(count)))

    def __len__(self) -> int:
        return self.images.shape[0]

    def subset(self, positions: list[int]) -> PosedImages:
        """The images at ``positions`` (0-based positions within this set), everything else shared."""
        index = torch.as_tensor(positions, dtype=torch.long)
        return PosedImages(
            images=self.images[index],
            T_world_cam=self.T_world_cam[index],
            intrinsics=self.intrinsics,
            near=self.near,
            far=self.far,
            normalization=self.normalization,
            names=[self.names[i] for i in positions],
            scene_bounds=self.scene_bounds,
            white_background=self.white_background,
            source=self.source,
            indices=[self.indices[i] for i in positions],
            depths=self.depths[index] if self.depths is not None else None,
            depth_intrinsics=self.depth_intrinsics,
            T_cam_depth=self.T_cam_depth,
        )

    def depth_poses(self) -> torch.Tensor:
        """(K, 4, 4) float64 poses of the depth camera: ``T_world_cam · T_cam_depth``."""
        poses = self.T_world_cam.double()
        return poses if self.T_cam_depth is None else poses @ self.T_cam_depth.double()

    def without_depth(self) -> PosedImages:
        """The same images without their depth images (RGB-only map building)."""
        return replace(self, depths=None, depth_intrinsics=None)

    def in_frame(self, normalization: MapNormalization) -> PosedImages:
        """The same images in the map frame of ``normalization`` (another map's frame over the same metric world,
        e.g. an SfM map aligned to this data set's ground truth by ``locnerf map align``).

        Poses go through the metric frame (``normalization.metric_to_map(self.normalization.map_to_metric(T))``);
        depths, near, far and ``T_cam_depth``'s translation are rescaled to the new map units, and the scene box is
        the box of its transformed corners. Between two NDC frames (forward-facing maps: an LLFF capture's and the
        map built from its images by structure from motion) the poses move the same way and the bounds are the
        target's (its NDC cube, near and far: NDC is the map's own warp). Returns ``self`` when both frames coincide.

        Raises:
            DatasetError: if one frame is NDC and the other not.
        """
        ours = self.normalization
        if torch.allclose(torch.tensor(ours.T_map_dataset), torch.tensor(normalization.T_map_dataset), atol=1e-9) and math.isclose(
            ours.scale, normalization.scale
        ):
            return self
        if ours.ndc != normalization.ndc:
            raise DatasetError(f"{self.source}: an NDC frame and one without NDC rays cannot be re-expressed in each other (expected both or neither)")
        moved = frame_change(ours, normalization)
        if ours.ndc:
            return replace(self, T_world_cam=moved(self.T_world_cam.double()), near=normalization.near, far=normalization.far, normalization=normalization)
        factor = normalization.scale / ours.scale
        corners = torch.cartesian_prod(*self.scene_bounds.double().T)
        corners = moved(_at(corners))[:, :3, 3]
        T_cam_depth = None
        if self.T_cam_depth is not None:
            T_cam_depth = self.T_cam_depth.double().clone()
            T_cam_depth[:3, 3] *= factor
        return replace(
            self,
            T_world_cam=moved(self.T_world_cam.double()),
            near=self.near * factor,
            far=self.far * factor,
            normalization=normalization,
            scene_bounds=torch.stack((corners.min(0).values, corners.max(0).values)),
            depths=None if self.depths is None else self.depths * factor,
            T_cam_depth=T_cam_depth,
        )


def frame_change(source: MapNormalization, target: MapNormalization) -> Callable[[torch.Tensor], torch.Tensor]:
    """Poses (..., 4, 4) in the map frame of ``source`` -> the same poses in that of ``target`` (through their common world)."""
    return lambda T: target.metric_to_map(source.map_to_metric(T))


def _at(points: torch.Tensor) -> torch.Tensor:
    """Poses (N, 4, 4) float64 with identity rotation at ``points`` (N, 3)."""
    poses = torch.eye(4, dtype=torch.float64).repeat(len(points), 1, 1)
    poses[:, :3, 3] = points.double()
    return poses
