"""What the filter loop's update requests carry, by configuration: keyframe-seeded first updates sized
by the ray budget, the exposure-invariant likelihood, re-projection, RGB-D depth parts, repeated updates."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from locnerf.config import preset
from locnerf.geometry.metrics import rotation_error_deg, translation_error
from locnerf.geometry.se3 import se3_exp
from locnerf.maps.keyframes import build_keyframe_index
from locnerf.messages.codec import encode_image
from locnerf.messages.schemas import DepthHeader, ImageHeader
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.__main__ import localizer_config
from locnerf_services.filter_loop.service import FilterLoopConfig
from tests.conftest import REPO_ROOT
from tests.services.filter_harness import Harness, image_payload, odometry_payload


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


def test_the_first_update_after_a_global_start_is_seeded_at_the_keyframes_and_sized_by_the_ray_budget(world):
    """A uniform start with ``keyframe_start.share = 0.9``: the first request already carries 270
    of the 300 particles around the 8 keyframes most like the image (one is 3 cm and 0.6° from the
    camera: some particles lie within 0.3 units and 10° of it, none of the uniform start did), and looks at
    ray_budget // 300 = 20 pixels instead of 64."""
    generator = torch.Generator().manual_seed(3)
    keyframe_poses = torch.stack([world.sample_camera_pose(generator) for _ in range(60)])
    camera = keyframe_poses[17] @ se3_exp(torch.tensor([0.0, 0.01, 0.0, 0.02, 0.0, -0.02], dtype=torch.float64))
    settings = preset("llff", keyframe_start={"share": 0.9}, measurement={"pixels": 64, "ray_budget": 6000})
    index = build_keyframe_index(world.render_rays, keyframe_poses, world.default_intrinsics)
    harness = Harness(world, localizer_config=settings, keyframes=index)
    harness.add_worker("w1")

    def near_camera(poses: torch.Tensor) -> int:
        poses, truth = poses.double(), camera.expand(len(poses), 4, 4)
        return int(((translation_error(poses, truth) < 0.3) & (rotation_error_deg(poses, truth) < 10.0)).sum())

    assert near_camera(harness.loop.localizer.particles.poses) == 0
    harness.collect(harness.loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
    harness.loop.predict_pending()
    harness.collect(harness.loop.handle_image(image_payload(world, 0.0, camera)))
    harness.tick()
    ((_, request),) = harness.requests
    assert len(request.pixels) == 20
    assert near_camera(torch.tensor(request.poses, dtype=torch.float64).reshape(-1, 4, 4)) > 0


def test_update_requests_carry_the_exposure_invariant_likelihood(world) -> None:
    """A localizer file that sets ``measurement.exposure_gain_range`` (configs/kitchen_single_image.toml)
    is scored the same way live: every shard of an update asks the workers for that range; without it, for none."""
    settings = localizer_config(str(REPO_ROOT / "configs" / "kitchen_single_image.toml"))
    assert settings.measurement.exposure_gain_range == (0.5, 2.0)
    for measurement, expected in ((settings.measurement.model_dump(), (0.5, 2.0)), ({}, None)):
        harness = Harness(world, localizer_config=preset("llff", measurement=measurement))
        harness.add_worker("w1")
        harness.add_worker("w2")
        harness.collect(harness.loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
        harness.loop.predict_pending()
        harness.collect(harness.loop.handle_image(image_payload(world, 0.0, world.sample_camera_pose(torch.Generator().manual_seed(0)))))
        harness.tick()
        assert len(harness.requests) == 2 and all(request.exposure_gain_range == expected for _, request in harness.requests)


def test_a_converged_cloud_is_weighed_by_reprojection_live(world) -> None:
    """With ``measurement.warp``: a tight cloud's update asks every worker for the same re-projection
    (reference pose, seed, image), and the answers merge like any other; a spread cloud renders."""
    truth = world.sample_camera_pose(torch.Generator().manual_seed(0))
    settings = preset("llff", measurement={"warp": {"max_spread": 0.05, "pixels": 64, "stride": 4}})
    for spread, warped in ((1e-3, True), (0.3, False)):
        harness = Harness(world, FilterLoopConfig(start="wait"), localizer_config=settings)
        harness.add_worker("w1")
        harness.add_worker("w2")
        covariance = torch.diag(torch.tensor([1e-4] * 3 + [spread**2] * 3, dtype=torch.float64))
        harness.start_at(truth, covariance)
        harness.collect(harness.loop.handle_image(image_payload(world, 0.0, truth)))
        harness.tick()
        warps = [request.warp for _, request in harness.requests]
        assert len(warps) == 2
        if not warped:
            assert warps == [None, None]
            continue
        assert warps[0] is not None and warps[0] == warps[1]
        reference = torch.tensor(warps[0].reference_pose, dtype=torch.float64)
        assert float(translation_error(reference, truth)) < 0.01
        while harness.requests:
            harness.answer(harness.requests.pop(0)[1])
        assert harness.loop.localizer.counters["merged"] == 1


def _rgbdimage_payload(world: ProceduralWorld, stamp: float, pose: torch.Tensor, depth_mm: np.ndarray, camera: PinholeIntrinsics) -> bytes:
    pixels = (world.render_image(pose) * 255).round().to(torch.uint8).numpy()
    intrinsics = world.default_intrinsics
    header = ImageHeader(
        stamp=stamp,
        encoding="rgb8",
        width=intrinsics.width,
        height=intrinsics.height,
        intrinsics=intrinsics,
        depth=DepthHeader(width=camera.width, height=camera.height, intrinsics=camera),
    )
    return encode_image(header, pixels, depth_mm)


def test_rgbd_frames_send_the_same_depth_part_to_every_worker(world) -> None:
    """With ``measurement.depth`` an RGB-D frame's update carries the depth image, its camera and the same
    depth pixels (valid readings) in every shard, and merges; a colour-only frame goes without (warned
    once); without ``measurement.depth`` the depth is not sent; a depth image with no reading is counted
    and the update goes on with colour alone."""
    truth = world.sample_camera_pose(torch.Generator().manual_seed(0))
    camera = PinholeIntrinsics(fx=20.0, fy=20.0, cx=10.0, cy=7.5, width=20, height=15)
    depth_mm = np.full((15, 20), 2000, dtype=np.uint16)
    depth_mm[:5] = 0
    with_depth = preset("llff", measurement={"depth": {"pixels": 12}})
    for settings, payload, sends in (
        (with_depth, _rgbdimage_payload(world, 0.0, truth, depth_mm, camera), True),
        (with_depth, image_payload(world, 0.0, truth), False),
        (preset("llff"), _rgbdimage_payload(world, 0.0, truth, depth_mm, camera), False),
        (with_depth, _rgbdimage_payload(world, 0.0, truth, np.zeros_like(depth_mm), camera), False),
    ):
        harness = Harness(world, FilterLoopConfig(start="wait"), localizer_config=settings)
        harness.add_worker("w1")
        harness.add_worker("w2")
        covariance = torch.diag(torch.tensor([1e-4] * 6, dtype=torch.float64))
        harness.start_at(truth, covariance)
        harness.collect(harness.loop.handle_image(payload))
        harness.tick()
        parts = [request.depth for _, request in harness.requests]
        assert len(parts) == 2
        if not sends:
            assert parts == [None, None]
            continue
        assert parts[0] is not None and parts[0] == parts[1]
        assert parts[0].intrinsics == camera and len(parts[0].pixels) == 12 and all(v >= 5 for _, v in parts[0].pixels)
        assert parts[0].image == depth_mm.astype("<u2").tobytes()
        while harness.requests:
            harness.answer(harness.requests.pop(0)[1])
        assert harness.loop.localizer.counters["merged"] == 1
        assert harness.loop.dispatcher.counters["updates_with_depth"] == 1
    assert harness.loop.counters()["depth_without_readings"] == 1 and harness.loop.bad.total == 0


def test_repeated_updates_on_one_image_wait_for_the_previous_merge(world) -> None:
    """``updates_per_image`` 2: the image's second update starts only after its first has merged, none
    after that, and a newer image starts afresh; with 1 (the default) an image is used once."""
    truth = world.sample_camera_pose(torch.Generator().manual_seed(0))
    for uses, expected in ((2, [1, 0, 1, 0, 1]), (1, [1, 0, 0, 0, 1])):
        harness = Harness(world, FilterLoopConfig(start="wait", updates_per_image=uses), localizer_config=preset("llff"))
        harness.add_worker("w1")
        covariance = torch.diag(torch.tensor([1e-4] * 3 + [1e-4] * 3, dtype=torch.float64))
        harness.start_at(truth, covariance)
        started = []
        for step in range(5):
            if step in (0, 4):
                harness.collect(harness.loop.handle_image(image_payload(world, 0.0, truth)))
            before = len(harness.requests)
            harness.tick()
            started.append(len(harness.requests) - before)
            if step >= 1:  # the first update stays in flight over the second tick
                while harness.requests:
                    harness.answer(harness.requests.pop(0)[1])
        assert started == expected


def test_after_the_refining_updates_shard_0_of_the_next_update_carries_a_search_whose_find_moves_the_cloud(world) -> None:
    """A keyframe start with one refining update and ``recovery.search``: the first update carries no search, the
    second carries one on its first shard only (the snapshot's weighted mean), the worker's find moves the cloud
    on the merge, and the third carries none."""
    generator = torch.Generator().manual_seed(3)
    keyframe_poses = torch.stack([world.sample_camera_pose(generator) for _ in range(60)])
    camera = keyframe_poses[17] @ se3_exp(torch.tensor([0.0, 0.01, 0.0, 0.02, 0.0, -0.02], dtype=torch.float64))
    settings = preset(
        "llff",
        keyframe_start={"share": 0.9, "refine_updates": 1},
        measurement={"pixels": 64, "ray_budget": 6000},
        # any spread: after one refining update the seeded cloud is still wider than the default search_max_spread
        recovery={"enabled": True, "search": {"start_position": 0.02, "iterations": 2, "candidates": 16, "elite": 4}, "search_max_spread": 10.0},
    )
    index = build_keyframe_index(world.render_rays, keyframe_poses, world.default_intrinsics)
    harness = Harness(world, FilterLoopConfig(updates_per_image=3), localizer_config=settings, keyframes=index)
    harness.add_worker("w1")
    harness.add_worker("w2")
    harness.collect(harness.loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
    harness.loop.predict_pending()
    harness.collect(harness.loop.handle_image(image_payload(world, 0.0, camera)))
    carried = []
    for _ in range(3):
        harness.tick()
        carried.append([request.search for _, request in harness.requests])
        while harness.requests:
            harness.answer(harness.requests.pop(0)[1])
    assert carried[0] == [None, None] and carried[2] == [None, None]
    search, other = carried[1]
    assert search is not None and other is None
    assert search.config == settings.recovery.search
    counters = harness.loop.localizer.counters
    assert (counters["merged"], counters["searches"], counters["searches_moved"]) == (3, 1, 1)
