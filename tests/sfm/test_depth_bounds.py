"""An SfM capture's near and far bounds (:func:`locnerf.sfm.forward_facing.image_depth_bounds`) on pycolmap's
synthetic reconstructions: points seen in two views only do not bound an image (a sparse low-resolution
capture's nearest point sets LLFF's 0.1th percentile, and one loose two-view point scaled the fern map's frame
by 1.43); points seen in three or more views do, as float64 percentiles of their depths."""

from __future__ import annotations

import numpy as np
import pytest

from locnerf.errors import DatasetError
from locnerf.sfm.forward_facing import BOUND_PERCENTILES, MIN_TRACK_LENGTH, image_depth_bounds

pycolmap = pytest.importorskip("pycolmap")


def _synthetic(points: int, seed: int = 0):
    """A reconstruction of 5 images of one camera seeing all ``points`` 3D points (pycolmap's synthetic data set)."""
    pycolmap.set_random_seed(seed)
    options = pycolmap.SyntheticDatasetOptions()
    options.num_rigs, options.num_cameras_per_rig, options.num_frames_per_rig, options.num_points3D = 1, 1, 5, points
    return pycolmap.synthesize_dataset(options)


def _names(reconstruction) -> list[str]:
    return sorted(image.name for image in reconstruction.images.values())


def _depth(image, xyz: np.ndarray) -> float:
    """``xyz``'s depth in ``image``'s camera, through pycolmap's own transform (the oracle's path)."""
    return float((image.cam_from_world() * xyz)[2])


def _add_point(reconstruction, image_ids: list[int], depth_fraction: float) -> int:
    """A point on the first image's viewing axis at ``depth_fraction`` of its nearest point's depth, observed in ``image_ids``
    through 2D features that had no 3D point."""
    first = reconstruction.images[image_ids[0]]
    nearest = min(_depth(first, reconstruction.points3D[p.point3D_id].xyz) for p in first.points2D if p.has_point3D())
    xyz = first.cam_from_world().inverse() * np.array([0.0, 0.0, depth_fraction * nearest])
    track = pycolmap.Track()
    for image_id in image_ids:
        free = next(k for k, p in enumerate(reconstruction.images[image_id].points2D) if not p.has_point3D())
        track.add_element(image_id, free)
    return reconstruction.add_point3D(xyz, track)


def _oracle(reconstruction, names: list[str], scale: float) -> np.ndarray:
    """(K, 2) float64 percentiles of each image's positive depths of the points seen in MIN_TRACK_LENGTH or more images."""
    by_name = {image.name: image for image in reconstruction.images.values()}
    rows = []
    for name in names:
        image = by_name[name]
        points = [reconstruction.points3D[p.point3D_id] for p in image.points2D if p.has_point3D()]
        depths = np.asarray([_depth(image, point.xyz) for point in points if point.track.length() >= MIN_TRACK_LENGTH], dtype=np.float64)
        rows.append(np.percentile(depths[depths > 0], BOUND_PERCENTILES) * scale)
    return np.asarray(rows)


def test_two_view_points_do_not_bound_an_image_and_three_view_points_do():
    reconstruction = _synthetic(60)
    names = _names(reconstruction)
    before = image_depth_bounds(reconstruction, names, scale=2.5)
    ids = sorted(reconstruction.images)
    loose = _add_point(reconstruction, ids[:2], 0.3)
    assert reconstruction.points3D[loose].track.length() == 2
    np.testing.assert_allclose(image_depth_bounds(reconstruction, names, scale=2.5), before, rtol=1e-12, atol=0)
    # A point seen in three views is a surface: it moves the near bound of the image it is nearest to.
    _add_point(reconstruction, ids[2:5], 0.8)
    after = image_depth_bounds(reconstruction, names, scale=2.5)
    np.testing.assert_allclose(after, _oracle(reconstruction, names, 2.5), rtol=1e-9, atol=0)
    moved = names.index(reconstruction.images[ids[2]].name)
    assert after[moved, 0] < 0.9 * before[moved, 0]


def test_an_image_with_too_few_multi_view_points_is_named():
    reconstruction = _synthetic(12)
    for point_id in sorted(reconstruction.points3D)[:3]:
        reconstruction.delete_point3D(point_id)
    names = _names(reconstruction)
    with pytest.raises(DatasetError, match=rf"{names[0]} \(9\)"):
        image_depth_bounds(reconstruction, names)
