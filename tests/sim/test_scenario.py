"""Simulated runs: odometry on the grid, the unseen kidnapping, sequence replay, segments."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

from locnerf.data import PosedImages, read_nerf_synthetic
from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, pose_inverse, rotation_error_deg, so3_exp, translation_error
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.paths import SequencePath, WorldPath
from locnerf.sim.scenario import ScenarioConfig, build_scenario, scenario_segments
from locnerf.sim.sensors import CameraConfig, VioConfig
from locnerf.sim.trajectory import FigureEightTrajectory
from locnerf.sim.world import ProceduralWorld

LEGO_ORBIT = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "nerf_synthetic" / "lego_test_orbit"
PERFECT_VIO = VioConfig(rate=15.0, translation_drift=0.0, yaw_drift_rate=0.0, rotation_noise=0.0, translation_noise=0.0)


def world_path() -> WorldPath:
    return WorldPath(ProceduralWorld.default("cpu"), FigureEightTrajectory(), CameraConfig())


def increments(poses: torch.Tensor) -> torch.Tensor:
    return pose_inverse(poses[:-1]) @ poses[1:]


def test_perfect_odometry_sees_every_step_but_the_kidnapping() -> None:
    path = world_path()
    plain = build_scenario(path, ScenarioConfig(duration=4.0, vio=PERFECT_VIO), MapNormalization())
    kidnapped = build_scenario(path, ScenarioConfig(duration=4.0, vio=PERFECT_VIO, kidnap_at=2.0), MapNormalization())
    jump = kidnapped.kidnap_tick
    assert jump == 30
    # The truth jumps far; before the jump everything is as without a kidnapping.
    assert float(translation_error(kidnapped.truth[jump], kidnapped.truth[jump - 1])) > 0.5
    torch.testing.assert_close(kidnapped.truth[:jump], plain.truth[:jump])
    seen = increments(kidnapped.odometry)
    # Across the jump the odometry reports the motion the camera would have made without it ...
    torch.testing.assert_close(seen[jump - 1], increments(plain.truth)[jump - 1], atol=1e-9, rtol=0)
    # ... and afterwards the true motion of the moved camera.
    torch.testing.assert_close(seen[jump:], increments(kidnapped.truth)[jump:], atol=1e-9, rtol=0)


def test_images_lie_on_the_odometry_grid_at_the_requested_rate() -> None:
    scenario = build_scenario(world_path(), ScenarioConfig(duration=3.0, image_rate=3.0, vio=PERFECT_VIO), MapNormalization())
    assert scenario.image_ticks == list(range(0, 46, 5))
    assert len(scenario.stamps) == 46


def test_image_rate_above_odometry_rate_is_refused() -> None:
    with pytest.raises(ValueError, match="image rate 30.0 Hz above the odometry rate 15.0 Hz"):
        build_scenario(world_path(), ScenarioConfig(duration=1.0, image_rate=30.0), MapNormalization())


def test_kidnapping_after_the_run_is_refused() -> None:
    with pytest.raises(ValueError, match="kidnap_at 5.0 s"):
        build_scenario(world_path(), ScenarioConfig(duration=2.0, kidnap_at=5.0), MapNormalization())


def tiny_sequence(count: int = 6) -> PosedImages:
    angles = torch.arange(count, dtype=torch.float64) * (2 * torch.pi / count)
    rotations = so3_exp(torch.stack([torch.zeros(count), angles, torch.zeros(count)], dim=-1).double())
    positions = torch.stack([4 * torch.sin(angles), torch.ones(count), 4 * torch.cos(angles)], dim=-1)
    intrinsics = PinholeIntrinsics(fx=8.0, fy=8.0, cx=4.0, cy=3.0, width=8, height=6)
    images = torch.arange(count, dtype=torch.float32)[:, None, None, None].expand(count, 6, 8, 3) / count
    return PosedImages(
        images=images.contiguous(),
        T_world_cam=make_pose(rotations, positions),
        intrinsics=intrinsics,
        near=0.1,
        far=10.0,
        normalization=MapNormalization(),
        names=[f"r_{i}" for i in range(count)],
        scene_bounds=torch.tensor([[-1.0] * 3, [1.0] * 3]),
    )


def test_sequence_path_passes_through_its_frames_along_geodesics() -> None:
    frames = tiny_sequence()
    step = float((frames.T_world_cam[1, :3, 3] - frames.T_world_cam[0, :3, 3]).norm())
    path = SequencePath(frames, speed=step * 3.0, odom_rate=15.0)
    assert path.frame_period * 15.0 == pytest.approx(5.0)
    stamps = torch.arange(len(frames) + 1, dtype=torch.float64) * path.frame_period
    torch.testing.assert_close(path.poses_at(stamps), torch.cat([frames.T_world_cam, frames.T_world_cam[:1]]))
    middle = path.poses_at(torch.tensor([0.5 * path.frame_period], dtype=torch.float64))[0]
    # Halfway along a pure yaw + chord: the rotation is half way, the position on the chord's screw.
    assert abs(float(rotation_error_deg(middle, frames.T_world_cam[0])) - 30.0) < 1e-9
    assert float(middle[1, 3]) == pytest.approx(1.0)
    scenario = build_scenario(path, ScenarioConfig(image_rate=3.0, vio=PERFECT_VIO, kidnap_at=0.5), MapNormalization())
    generator = torch.Generator().manual_seed(0)
    for tick in scenario.image_ticks:
        frame = round(float(scenario.path_times[tick]) / path.frame_period) % len(frames)
        torch.testing.assert_close(scenario.image(tick, generator), frames.images[frame])
        torch.testing.assert_close(scenario.truth[tick], frames.T_world_cam[frame])


def test_an_rgbd_sequence_gives_each_image_its_depth_and_a_colour_one_none() -> None:
    """Each image tick's depth image is its frame's, with the depth camera; the world's camera has none."""
    frames = tiny_sequence()
    depth_camera = PinholeIntrinsics(fx=4.0, fy=4.0, cx=2.0, cy=1.5, width=4, height=3)
    depths = torch.arange(len(frames), dtype=torch.float32)[:, None, None].expand(len(frames), 3, 4).contiguous() + 1.0
    path = SequencePath(dataclasses.replace(frames, depths=depths, depth_intrinsics=depth_camera), speed=1.0, odom_rate=15.0, frame_rate=15.0)
    scenario = build_scenario(path, ScenarioConfig(duration=0.3, image_rate=5.0, vio=PERFECT_VIO), MapNormalization())
    for tick in scenario.image_ticks:
        depth = scenario.depth(tick)
        assert depth is not None and depth.intrinsics == depth_camera
        torch.testing.assert_close(depth.depth, depths[round(float(scenario.path_times[tick]) / path.frame_period) % len(frames)])
    assert SequencePath(frames, speed=1.0, odom_rate=15.0).depth_at(0.0) is None
    assert world_path().depth_at(0.0) is None


def test_sequence_replays_at_its_capture_rate() -> None:
    """At 30 frames/s under 15 Hz odometry every tick is every second frame, and 5 Hz images are every sixth frame."""
    frames = tiny_sequence(count=12)
    path = SequencePath(frames, speed=1.0, odom_rate=15.0, frame_rate=30.0)
    assert path.frame_period == pytest.approx(1 / 30)
    scenario = build_scenario(path, ScenarioConfig(duration=0.6, image_rate=5.0, vio=PERFECT_VIO), MapNormalization())
    assert scenario.image_ticks == [0, 3, 6, 9]
    generator = torch.Generator().manual_seed(0)
    for tick in scenario.image_ticks:
        torch.testing.assert_close(scenario.image(tick, generator), frames.images[(2 * tick) % len(frames)])
    torch.testing.assert_close(scenario.truth, frames.T_world_cam[[(2 * k) % len(frames) for k in range(10)]])


@pytest.mark.parametrize("frame_rate", [20.0, 7.5, 0.0])
def test_capture_rate_must_be_a_multiple_of_the_odometry_rate(frame_rate: float) -> None:
    with pytest.raises(LocnerfInputError, match=f"frame rate {frame_rate} Hz: expected a whole multiple of the odometry rate 15.0 Hz"):
        SequencePath(tiny_sequence(), speed=1.0, odom_rate=15.0, frame_rate=frame_rate)


def test_image_rate_above_the_sequence_frame_rate_is_refused() -> None:
    """Frames 0.2 s apart (the lego orbit at its nominal speed) give at most 5 images per second: 10 Hz
    is refused rather than silently replayed at 5 Hz."""
    frames = tiny_sequence(count=12)
    step = float((frames.T_world_cam[1:, :3, 3] - frames.T_world_cam[:-1, :3, 3]).norm(dim=-1).mean())
    path = SequencePath(frames, speed=step / 0.2, odom_rate=15.0)
    assert path.frame_period == pytest.approx(0.2)
    assert len(path.image_times(5.0, 15.0, 1.0)) == 6
    with pytest.raises(LocnerfInputError, match="image rate 10.0 Hz above the sequence's 5 frames per second"):
        path.image_times(10.0, 15.0, 1.0)


def test_sequence_needs_two_frames() -> None:
    with pytest.raises(ValueError, match="1 frame"):
        SequencePath(tiny_sequence().subset([0]), speed=1.0, odom_rate=15.0)


@pytest.mark.skipif(not LEGO_ORBIT.is_dir(), reason="the shared data set ../shared/data/nerf_synthetic/lego_test_orbit is absent")
def test_lego_orbit_replays_as_a_closed_loop() -> None:
    frames = read_nerf_synthetic(LEGO_ORBIT, split="test", background="white", downscale=8)
    assert len(frames) == 200 and (frames.intrinsics.width, frames.intrinsics.height) == (50, 50)
    path = SequencePath(frames, speed=0.66, odom_rate=15.0)
    assert path.frame_period * 15.0 == pytest.approx(5.0)  # mean frame spacing 0.22 units at 0.66 units/s: 1/3 s
    scenario = build_scenario(path, ScenarioConfig(duration=10.0, image_rate=3.0, vio=PERFECT_VIO), MapNormalization())
    assert scenario.image_ticks == list(range(0, 151, 5))
    torch.testing.assert_close(scenario.truth[scenario.image_ticks], frames.T_world_cam[:31])
    # The white background of the RGBA frames is kept: corners are white.
    assert float(frames.images[:, 0, 0].min()) > 0.99


@pytest.mark.parametrize("segment_ticks", [7, 10])
def test_segments_continue_the_odometry_and_join_into_the_whole_run(segment_ticks: int) -> None:
    """Without white noise the run is deterministic, so its segments (the kidnapping at tick 30
    inside one, or at the start of one) must give exactly the whole run: truth, drifting odometry,
    image stamps and the jump."""
    drifting = VioConfig(translation_drift=0.03, yaw_drift_rate=0.05, rotation_noise=0.0, translation_noise=0.0)
    config = ScenarioConfig(duration=4.0, image_rate=3.0, vio=drifting, kidnap_at=2.0)
    whole = build_scenario(world_path(), config, MapNormalization())
    segments = list(scenario_segments(world_path(), config, MapNormalization(), segment_ticks=segment_ticks))
    assert [len(s.stamps) for s in segments[:-1]] == [segment_ticks] * (len(segments) - 1)
    torch.testing.assert_close(torch.cat([s.truth for s in segments]), whole.truth, atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.cat([s.odometry for s in segments]), whole.odometry, atol=1e-9, rtol=0)
    offsets = [segment_ticks * i for i in range(len(segments))]
    assert [o + t for o, s in zip(offsets, segments) for t in s.image_ticks] == whole.image_ticks
    assert [o + s.kidnap_tick for o, s in zip(offsets, segments) if s.kidnap_tick is not None] == [whole.kidnap_tick] == [30]


def test_a_segment_needs_a_stamp() -> None:
    with pytest.raises(ValueError, match="segment_ticks 0"):
        scenario_segments(world_path(), ScenarioConfig(duration=1.0), MapNormalization(), segment_ticks=0)
