"""The surface-distance layer of a map, from the depth images of the frames it is built from."""

from __future__ import annotations

from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import depth_points
from locnerf.errors import DatasetError
from locnerf.field.surface_distance import SurfaceDistance, SurfaceDistanceConfig


def surface_distance_of_frames(images: PosedImages, config: SurfaceDistanceConfig) -> SurfaceDistance:
    """The layer (:mod:`locnerf.field.surface_distance`) of every valid depth reading of ``images``, placed by
    their depth cameras (:meth:`PosedImages.depth_poses`) in the map frame.

    Raises:
        DatasetError: without depth images, for NDC (forward-facing) data, or when no reading is valid.
    """
    if images.depths is None or images.depth_intrinsics is None:
        raise DatasetError(f"{images.source}: a surface-distance layer needs depth images")
    if images.normalization.ndc:
        raise DatasetError(f"{images.source}: a surface-distance layer needs a metric map, not NDC (forward-facing) data")
    points = depth_points(images.depths, images.depth_poses(), images.depth_intrinsics)
    if len(points) == 0:
        raise DatasetError(f"{images.source}: no valid depth reading in {len(images)} frames; expected depth images with readings")
    return SurfaceDistance.from_points(points, config)
