"""The re-projection ceiling (``locnerf map ceiling``) on the procedural world, where every answer is known.

The world renders exactly what its RGB-D frames recorded (colour camera off the depth camera by the known
offset of ``tests/data/rgbd_world``, exact depth images, Lambertian colours), so training frames
re-projected into a held-out frame through its depth agree with it up to bilinear reads, and the world
used as the map agrees too. A held-out frame darkened to 70 % (another exposure) keeps its coverage
and its colour-fitted ceiling while the plain ceiling drops by about what the darkening costs.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from locnerf.data.colour_camera import with_colour_camera
from locnerf.errors import DatasetError
from locnerf.eval.reprojection_ceiling import SUMMARY_KEYS, reprojection_ceiling
from locnerf.sim.world import ProceduralWorld
from tests.data.rgbd_world import TRUE_OFFSET, rgbd_sequence


@pytest.fixture(scope="module")
def world_and_frames():
    world = ProceduralWorld.default()
    frames = with_colour_camera(rgbd_sequence(world, frames=16), TRUE_OFFSET)
    return world, frames.subset(list(range(0, 16, 2))), frames.subset([5, 9])


def test_frames_of_the_same_pass_are_covered_and_re_projected_closely(world_and_frames) -> None:
    """Measured when written: coverage 0.99 / 0.99, ceiling 37.0 / 88.8 dB (bilinear reads), the world as the map
    exact (120 dB, the MSE floor). Bounds: coverage ≥ 0.9, ceiling ≥ 30 dB, the world itself ≥ 60 dB."""
    world, training, views = world_and_frames
    report = reprojection_ceiling(views, training, world.render_rays)
    assert [row["name"] for row in report["views"]] == views.names
    assert report["summary"]["views"] == 2 and set(SUMMARY_KEYS) <= set(report["summary"])
    for row in report["views"]:
        assert row["coverage"] >= 0.9, row
        assert row["ceiling_psnr"] >= 30.0 and row["ceiling_psnr_colour_fitted"] >= row["ceiling_psnr"] - 1e-6, row
        assert row["map_psnr_covered"] >= 60.0 and row["map_psnr"] >= 60.0, row


def test_another_exposure_lowers_the_plain_ceiling_but_not_the_colour_fitted_one(world_and_frames) -> None:
    """Measured when written, darkened: ceiling 15.8 dB, colour-fitted 66.0 dB, coverage unchanged (0.99)."""
    world, training, views = world_and_frames
    bright = reprojection_ceiling(views, training, world.render_rays)["summary"]
    darkened = reprojection_ceiling(replace(views, images=views.images * 0.7), training, world.render_rays)["summary"]
    assert darkened["coverage"] == pytest.approx(bright["coverage"])
    assert darkened["ceiling_psnr"] < bright["ceiling_psnr"] - 5.0
    assert darkened["ceiling_psnr_colour_fitted"] > bright["ceiling_psnr_colour_fitted"] - 3.0  # the fitted gain takes the 0.7 back


def test_frames_without_depth_are_refused(world_and_frames) -> None:
    world, training, views = world_and_frames
    with pytest.raises(DatasetError, match="needs depth images in the held-out views"):
        reprojection_ceiling(views.without_depth(), training, world.render_rays)
