"""Query images on the lens a map was built for: a map posed by structure from motion records its camera's
distortion, and a data set's frames read to meet that map are resampled onto the map's pinhole camera.

``locnerf map build --sfm`` undistorts its training images with the camera COLMAP estimated (for the kitchen:
522.1 px and k1 = -0.031 at 640×480) and records it in the map's ``sfm`` metadata (:data:`CAMERA_KEY`). A data
set's reader gives the same physical camera its own pinhole model (7-Scenes: 525.5 px, no distortion), which
casts rays up to 0.7° away from the map's in the image corners. :func:`on_map_lens` resamples each image
through the recorded lens onto the map's camera (``cv2.undistort`` with the map's camera as the new matrix), so
the queries' rays are the ones the map was trained with.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict

from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError
from locnerf.render.camera import PinholeIntrinsics

CAMERA_KEY = "camera"
"""Entry of a map's ``sfm`` metadata: ``{"intrinsics": PinholeIntrinsics fields at full size, "distortion": [k1, k2, p1, p2]}``."""


def lens_record(intrinsics: PinholeIntrinsics, distortion: np.ndarray) -> dict:
    """The :data:`CAMERA_KEY` entry of a camera (pinhole part at the images' full size, OpenCV distortion)."""
    return {"intrinsics": intrinsics.model_dump(), "distortion": [float(v) for v in distortion]}


class MapLens(BaseModel):
    """The lens an SfM map records and the pinhole camera it was trained with: what a query image is resampled through.

    ``lens``: the full-size pinhole part of the estimated camera; ``distortion``: its OpenCV (k1, k2, p1, p2);
    ``camera``: the map's own pinhole camera (its ``default_intrinsics``). A plain record, so that a service (the
    ingest replaying a data set for a live run) can be handed it in its configuration.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    lens: PinholeIntrinsics
    distortion: tuple[float, float, float, float]
    camera: PinholeIntrinsics

    def apply(self, frames: PosedImages) -> PosedImages:
        """``frames`` resampled through the lens onto the map's camera, at the frames' own size.

        Raises:
            DatasetError: if the frames' aspect ratio is not the lens's.
        """
        width, height = frames.intrinsics.width, frames.intrinsics.height
        if abs(width * self.lens.height - height * self.lens.width) > max(width, height):
            raise DatasetError(f"{frames.source}: images of {width}x{height} do not have the map's camera's aspect ({self.lens.width}x{self.lens.height})")
        raw = self.lens.scaled(width / self.lens.width).matrix().numpy()
        target = self.camera.scaled(width / self.camera.width)
        distortion = np.asarray(self.distortion, dtype=np.float64)
        map_x, map_y = cv2.initUndistortRectifyMap(raw, distortion, None, target.matrix().numpy(), (width, height), cv2.CV_32FC1)
        images = [cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR) for image in frames.images.numpy()]  # the maps once, not per image
        return replace(frames, images=torch.from_numpy(np.stack(images)), intrinsics=target)


def map_lens(radiance_map: object) -> MapLens | None:
    """The :class:`MapLens` of a map whose ``sfm`` metadata records a lens (with the map's ``default_intrinsics``); None for other maps.

    Raises:
        DatasetError: for an entry that is not a camera and four distortion coefficients.
    """
    record = ((getattr(radiance_map, "metadata", None) or {}).get("sfm") or {}).get(CAMERA_KEY)
    if record is None:
        return None
    try:
        intrinsics = PinholeIntrinsics(**record["intrinsics"])
        distortion = np.asarray(record["distortion"], dtype=np.float64).reshape(4)
    except (KeyError, TypeError, ValueError) as error:
        raise DatasetError(f"map metadata sfm.{CAMERA_KEY}: expected intrinsics and 4 distortion coefficients, got {record!r} ({error})") from None
    return MapLens(lens=intrinsics, distortion=tuple(float(v) for v in distortion), camera=radiance_map.default_intrinsics)


def on_map_lens(frames: PosedImages, radiance_map: object) -> PosedImages:
    """``frames`` resampled onto ``radiance_map``'s camera through the lens its metadata records (:func:`map_lens`);
    as they are for maps that record none.

    Args:
        frames: images taken with the map's physical camera (any reader's pinhole model of it), same aspect ratio.
        radiance_map: a map with ``metadata`` and ``default_intrinsics``.
    Raises:
        DatasetError: if the frames' aspect ratio is not the lens's.
    """
    lens = map_lens(radiance_map)
    return frames if lens is None else lens.apply(frames)
