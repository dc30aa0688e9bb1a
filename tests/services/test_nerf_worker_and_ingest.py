"""The worker against the measurement model it wraps; the ingest's events, odometry and pacing."""

from __future__ import annotations

import dataclasses
import itertools
import math

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.detect import read_dataset
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import depth_points
from locnerf.field.protocol import MapNormalization
from locnerf.field.surface_distance import SurfaceDistance, SurfaceDistanceConfig
from locnerf.filter.depth_measurement import (
    DepthConfig,
    DepthObservation,
    render_depth_image,
    rendered_depth_log_likelihoods,
    sample_depth_pixels,
    surface_distance_log_likelihoods,
    warped_depth_log_likelihoods,
)
from locnerf.filter.measurement import observed_colours, particle_log_likelihoods, sample_pixels
from locnerf.filter.measurement_config import MeasurementConfig, WarpConfig
from locnerf.filter.search_config import CrossEntropyConfig
from locnerf.filter.warp import render_reference, warp_log_likelihoods
from locnerf.geometry.metrics import translation_error
from locnerf.geometry.se3 import make_pose, pose_inverse, se3_exp
from locnerf.geometry.so3 import so3_exp
from locnerf.messages.codec import decode, decode_image, decode_rgbd, encode
from locnerf.messages.schemas import DepthRequest, Odometry, SearchRequest, UpdateRequest, WarpRequest
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, depth_millimetres
from locnerf.sim.sensors import VioConfig, simulate_odometry
from locnerf.sim.world import ProceduralWorld
from locnerf_services.nerf_worker.service import NerfWorker, RequestError
from locnerf_services.rgbd import depth_observation
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from locnerf_services.sensor_ingest.camera_source import CameraSourceConfig, camera_events
from locnerf_services.sensor_ingest.replay_source import ReplaySourceConfig, replay_events
from locnerf_services.sensor_ingest.service import Pacer, event_message
from locnerf_services.sensor_ingest.world_source import WorldSourceConfig, world_events


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


def _request(world: ProceduralWorld, generator: torch.Generator, count: int = 6) -> tuple[UpdateRequest, torch.Tensor, torch.Tensor, torch.Tensor]:
    poses = torch.stack([world.sample_camera_pose(generator) for _ in range(count)]).float()
    intrinsics = world.default_intrinsics
    image = world.render_image(poses[0].double())
    pixels = sample_pixels(intrinsics.height, intrinsics.width, 16, generator)
    colours = observed_colours(image, pixels)
    request = UpdateRequest(
        request_id="r",
        shard=0,
        map_checksum=world.checksum,
        epoch=1,
        generation=0,
        ids=list(range(10, 10 + count)),
        poses=poses.reshape(count, 16).tolist(),
        pixels=pixels.tolist(),
        observed_rgb=colours.tolist(),
        intrinsics=intrinsics,
    )
    return request, poses, pixels, colours


def test_worker_result_equals_the_measurement_model(world, generator):
    request, poses, pixels, colours = _request(world, generator)
    result = NerfWorker(world, "w").handle(request)
    expected = particle_log_likelihoods(poses, pixels, colours, world.default_intrinsics, world.render_rays)
    assert result.ids == request.ids and (result.epoch, result.generation) == (1, 0)
    torch.testing.assert_close(torch.tensor(result.log_likelihoods, dtype=torch.float64), expected)
    assert int(torch.tensor(result.log_likelihoods).argmax()) == 0  # the particle at the true pose wins


def test_worker_applies_the_requested_exposure_invariant_likelihood(world, generator):
    """A request with ``exposure_gain_range`` is scored as the in-process localizer scores it (the oracle:
    the measurement model with the same range), which differs from the plain likelihood on a darkened image;
    a range that excludes the identity gain is refused when the request is built."""
    request, poses, pixels, colours = _request(world, generator)
    darker = request.model_copy(update={"observed_rgb": (0.7 * colours).tolist(), "exposure_gain_range": (0.5, 2.0)})
    result = NerfWorker(world, "w").handle(darker)
    expected = particle_log_likelihoods(poses, pixels, 0.7 * colours, world.default_intrinsics, world.render_rays, exposure_gain_range=(0.5, 2.0))
    plain = particle_log_likelihoods(poses, pixels, 0.7 * colours, world.default_intrinsics, world.render_rays)
    torch.testing.assert_close(torch.tensor(result.log_likelihoods, dtype=torch.float64), expected)
    assert not torch.allclose(expected, plain)
    with pytest.raises(ValueError, match=r"exposure_gain_range=\(1.5, 2.0\): expected 0 < low <= 1 <= high"):
        UpdateRequest.model_validate(request.model_dump() | {"exposure_gain_range": (1.5, 2.0)})


def _search_case(world: ProceduralWorld, generator: torch.Generator) -> tuple[UpdateRequest, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A request of two particles (16 pixels of the first one's image), the first one's pose as the truth (4, 4), a
    search start 3 cm from it, and 256 pixels (256, 2) with their colours (256, 3) seen from the truth."""
    request, poses, _, _ = _request(world, generator, count=2)
    truth = poses[0].double()
    intrinsics = world.default_intrinsics
    pixels = sample_pixels(intrinsics.height, intrinsics.width, 256, generator)
    start = truth @ se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.03, 0.0, 0.0], dtype=torch.float64))
    return request, truth, start, pixels, observed_colours(world.render_image(truth), pixels)


def test_worker_searches_on_the_requests_own_likelihood(world, generator):
    """A request carrying a search answers with the best pose the cross-entropy search found from a start 3 cm off,
    scored on the request's own pixels: its reported log-likelihood is the measurement model's at that pose (the oracle),
    at least the start's, and the pose lies closer to the camera than the start; a request without one answers none."""
    request, truth, start, pixels, colours = _search_case(world, generator)
    intrinsics = world.default_intrinsics
    search = SearchRequest(
        mean=start.tolist(), covariance=torch.eye(6).mul(1e-8).tolist(), config=CrossEntropyConfig(start_position=0.03, start_rotation_deg=1.0), seed=4
    )
    request = request.model_copy(update={"pixels": pixels.tolist(), "observed_rgb": colours.tolist(), "search": search})
    found = NerfWorker(world, "w").handle(request).search
    pose = torch.tensor(found.pose, dtype=torch.float64)
    expected = particle_log_likelihoods(torch.stack((pose, start)).float(), pixels, colours, intrinsics, world.render_rays)
    assert found.log_likelihood == pytest.approx(float(expected[0]), abs=1e-3)
    assert found.start_log_likelihood == pytest.approx(float(expected[1]), abs=1e-3)
    assert found.log_likelihood >= found.start_log_likelihood
    assert float(translation_error(pose, truth)) < float(translation_error(start, truth))
    assert NerfWorker(world, "w").handle(request.model_copy(update={"search": None})).search is None


def test_worker_searches_on_the_searchs_own_pixels_when_it_brings_them(world, generator):
    """A search that brings its own 256 pixels is scored on them (the oracle: the measurement model on those pixels at
    the found pose and at the start), while the shard's own log-likelihoods stay those of its 16 pixels; its pixels
    outside the image are a bad request, and a search request with pixels but no colours is refused when built."""
    request, truth, start, own, own_colours = _search_case(world, generator)
    poses = torch.tensor(request.poses, dtype=torch.float32).reshape(-1, 4, 4)
    pixels, colours = torch.tensor(request.pixels), torch.tensor(request.observed_rgb)
    intrinsics = world.default_intrinsics
    config = CrossEntropyConfig(start_position=0.03, start_rotation_deg=1.0, pixels=256)
    search = SearchRequest(
        mean=start.tolist(), covariance=torch.eye(6).mul(1e-8).tolist(), config=config, seed=4, pixels=own.tolist(), observed_rgb=own_colours.tolist()
    )
    result = NerfWorker(world, "w").handle(request.model_copy(update={"search": search}))
    pose = torch.tensor(result.search.pose, dtype=torch.float64)
    expected = particle_log_likelihoods(torch.stack((pose, start)).float(), own, own_colours, intrinsics, world.render_rays)
    assert result.search.log_likelihood == pytest.approx(float(expected[0]), abs=1e-3)
    assert result.search.start_log_likelihood == pytest.approx(float(expected[1]), abs=1e-3)
    assert float(translation_error(pose, truth)) < float(translation_error(start, truth))
    shard = particle_log_likelihoods(poses, pixels, colours, intrinsics, world.render_rays)
    torch.testing.assert_close(torch.tensor(result.log_likelihoods, dtype=torch.float64), shard)
    outside = search.model_copy(update={"pixels": [[500.0, 1.0]] * 256})
    with pytest.raises(RequestError, match="inside the 160×120 image"):
        NerfWorker(world, "w").handle(request.model_copy(update={"search": outside}))
    with pytest.raises(ValueError, match="both pixels and observed_rgb, or neither"):
        SearchRequest.model_validate(search.model_dump() | {"observed_rgb": None})
    with pytest.raises(ValueError, match=r"pixels \(M, 2\) and observed_rgb \(M, 3\) of equal length"):
        SearchRequest.model_validate(search.model_dump() | {"observed_rgb": own_colours[:10].tolist()})


def test_worker_rejects_pixels_outside_the_image_and_non_rigid_poses(world, generator):
    request, *_ = _request(world, generator, count=2)
    with pytest.raises(RequestError, match="inside the 160×120 image"):
        NerfWorker(world, "w").handle(request.model_copy(update={"pixels": [[500.0, 1.0]] * len(request.pixels)}))
    sheared = [[2.0] + pose[1:] for pose in request.poses]
    with pytest.raises(RequestError):
        NerfWorker(world, "w").handle(request.model_copy(update={"poses": sheared}))


QUIET_VIO = VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, rotation_noise=0.0, translation_noise=0.0)


def test_noiseless_odometry_reproduces_the_true_increments(generator):
    """The ingest's odometry model (locnerf.sim.sensors, the evaluation's; the random-walk model it replaced had its own test here)."""
    truths = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    truths[1, :3, 3] = torch.tensor([1.0, 0.0, 0.0])
    truths[2, :3, 3] = torch.tensor([1.0, 2.0, 0.5])
    out = simulate_odometry(truths, QUIET_VIO, generator)
    torch.testing.assert_close(pose_inverse(out[0]) @ out[2], pose_inverse(truths[0]) @ truths[2])
    with pytest.raises(ValueError, match=r"start"):
        simulate_odometry(truths, QUIET_VIO, generator, start=2 * torch.eye(4, dtype=torch.float64))


def test_yaw_drift_accumulates_at_its_rate(generator):
    rate = math.radians(2.0)
    still = torch.eye(4, dtype=torch.float64).repeat(11, 1, 1)  # 1 s at 10 Hz
    last = simulate_odometry(still, QUIET_VIO.model_copy(update={"rate": 10.0, "yaw_drift_rate": rate}), generator)[-1]
    assert math.isclose(math.atan2(last[0, 2], last[0, 0]), rate * 1.0, rel_tol=1e-9)


def test_world_stream_is_time_ordered_with_the_configured_rates(world):
    config = WorldSourceConfig(duration=1.0, image_rate=5.0, vio=VioConfig(rate=15.0))
    events = list(world_events(world, config, seed=0))
    stamps = [e.stamp for e in events]
    assert stamps == sorted(stamps)
    counts = {kind: sum(isinstance(e, kind) for e in events) for kind in (OdometryEvent, GroundTruthEvent, ImageEvent)}
    assert counts == {OdometryEvent: 16, GroundTruthEvent: 16, ImageEvent: 6}  # the simulator's grid: 0 .. 1 s, both ends
    key, payload = event_message("r", next(e for e in events if isinstance(e, ImageEvent)))
    header, pixels = decode_image(payload)
    assert key == "locnerf/r/sensors/image" and pixels.shape == (120, 160, 3) and header.intrinsics == world.default_intrinsics
    key, payload = event_message("r", next(e for e in events if isinstance(e, OdometryEvent)))
    assert key == "locnerf/r/sensors/odom" and decode(payload, Odometry).stamp == 0.0


def test_world_stream_with_distinct_frames_sends_the_first_ones_again(world):
    config = WorldSourceConfig(duration=1.0, image_rate=5.0, vio=VioConfig(rate=15.0), distinct_frames=2)
    frames = [e.pixels for e in world_events(world, config, seed=0) if isinstance(e, ImageEvent)]
    assert len(frames) == 6 and not (frames[0] == frames[1]).all()
    assert all(frames[k] is frames[k % 2] for k in range(2, 6))


def test_world_stream_without_images_is_odometry_only(world):
    events = list(world_events(world, WorldSourceConfig(duration=2.0, image_rate=0.0), seed=0))
    assert len(events) == 2 * 31 and not any(isinstance(e, ImageEvent) for e in events)


def test_pacer_waits_for_scaled_stamps():
    now = [100.0]
    sleeps: list[float] = []

    def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        now[0] += seconds

    events = [GroundTruthEvent(t, torch.eye(4)) for t in (5.0, 5.5, 7.0)]
    out = list(Pacer(speed=2.0, clock=lambda: now[0], sleep=sleep).paced(events))
    assert out == events and sleeps == pytest.approx([0.25, 0.75])
    assert list(Pacer(speed=0.0, clock=lambda: now[0], sleep=sleep).paced(events)) == events and len(sleeps) == 2


def _sequence(count: int) -> PosedImages:
    intrinsics = PinholeIntrinsics(fx=8.0, fy=8.0, cx=4.0, cy=3.0, width=8, height=6)
    steps = torch.zeros(count, 6, dtype=torch.float64)
    steps[:, 4] = torch.arange(count, dtype=torch.float64)  # 1 map unit along y per frame
    normalization = MapNormalization(scale=2.0)  # 2 map units per metre
    return PosedImages(
        images=torch.rand(count, 6, 8, 3),
        T_world_cam=se3_exp(steps),
        intrinsics=intrinsics,
        near=0.1,
        far=5.0,
        normalization=normalization,
        names=[str(i) for i in range(count)],
        scene_bounds=torch.tensor([[-1.0] * 3, [1.0] * 3]),
    )


def test_replay_interpolates_between_frames_in_metres(generator):
    sequence = _sequence(3)
    quiet = QUIET_VIO.model_copy(update={"rate": 4.0})
    events = list(replay_events(sequence, ReplaySourceConfig(frame_rate=2.0, vio=quiet), generator))
    images = [e for e in events if isinstance(e, ImageEvent)]
    truth = {e.stamp: e.T_world_cam for e in events if isinstance(e, GroundTruthEvent)}
    assert [e.stamp for e in images] == [0.0, 0.5, 1.0] and images[1].pixels.shape == (6, 8, 3)
    assert sorted(truth) == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert float(truth[0.75][1, 3]) == pytest.approx(0.75)  # frame 1.5 -> 1.5 map units -> 0.75 m
    odometry = [e for e in events if isinstance(e, OdometryEvent)]
    torch.testing.assert_close(pose_inverse(odometry[0].T_odom_body) @ odometry[-1].T_odom_body, pose_inverse(truth[0.0]) @ truth[1.0])


def test_replay_of_an_rgbd_sequence_sends_its_depth_in_millimetres(generator):
    """Depth in map units (2 per metre here) leaves as uint16 millimetres after the colour pixels;
    the filter's decoder gets it back, and readings uint16 cannot hold become 0 (no reading)."""
    depth_camera = PinholeIntrinsics(fx=4.0, fy=4.0, cx=2.0, cy=1.5, width=4, height=3)
    depths = torch.full((3, 3, 4), 3.0)  # 1.5 m
    depths[:, 0, 0] = 0.0
    depths[:, 0, 1] = 200.0  # 100 m: beyond uint16 millimetres
    sequence = dataclasses.replace(_sequence(3), depths=depths, depth_intrinsics=depth_camera)
    images = [e for e in replay_events(sequence, ReplaySourceConfig(frame_rate=2.0, vio=QUIET_VIO), generator) if isinstance(e, ImageEvent)]
    assert all(e.depth is not None and e.depth.intrinsics == depth_camera for e in images)
    expected = np.full((3, 4), 1500, dtype=np.uint16)
    expected[0, :2] = 0
    header, pixels, depth = decode_rgbd(event_message("r", images[1])[1])
    assert np.array_equal(depth, expected) and header.depth.intrinsics == depth_camera and np.array_equal(pixels, images[1].pixels)
    assert all(e.depth is None for e in replay_events(_sequence(2), ReplaySourceConfig(), generator) if isinstance(e, ImageEvent))
    with pytest.raises(ValueError, match=r"depth image: expected shape \(H, W\), got \(1, 3, 4\)"):
        depth_millimetres(depths[:1])


def test_lego_orbit_replays_from_the_shared_data(shared_data, generator):
    config = ReplaySourceConfig(path=str(shared_data / "nerf_synthetic" / "lego"), split="test", downscale=8, skip_missing=True)
    sequence = read_dataset(config.path, split=config.split, downscale=config.downscale, skip_missing=config.skip_missing)
    first = list(itertools.islice(replay_events(sequence, config, generator), 12))
    assert isinstance(first[0], GroundTruthEvent) and any(isinstance(e, ImageEvent) and e.pixels.shape == (100, 100, 3) for e in first)


def test_a_replay_without_a_path_is_refused():
    with pytest.raises(ValueError, match="replay.path"):
        sensor_events(IngestConfig(source="replay"))


def test_a_video_file_becomes_stamped_rgb_frames(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (32, 24))
    for value in range(5):
        frame = np.zeros((24, 32, 3), np.uint8)
        frame[..., 2] = 50 * value  # red in BGR order
        writer.write(frame)
    writer.release()
    intrinsics = PinholeIntrinsics(fx=30.0, fy=30.0, cx=16.0, cy=12.0, width=32, height=24)
    events = list(camera_events(CameraSourceConfig(device=str(path), intrinsics=intrinsics)))
    assert len(events) == 5 and [e.stamp for e in events] == sorted(e.stamp for e in events)
    assert events[-1].stamp == pytest.approx(0.4, abs=0.051)
    assert abs(int(events[4].pixels[..., 0].mean()) - 200) <= 8 and int(events[4].pixels[..., 2].mean()) <= 8  # now RGB
    with pytest.raises(ValueError, match="expected 64×24"):
        list(camera_events(CameraSourceConfig(device=str(path), intrinsics=intrinsics.model_copy(update={"width": 64}))))
    with pytest.raises(ValueError, match="cannot be opened"):
        list(camera_events(CameraSourceConfig(device=str(tmp_path / "missing.avi"), intrinsics=intrinsics)))


def _warp_request(world: ProceduralWorld, generator: torch.Generator) -> tuple[UpdateRequest, torch.Tensor, torch.Tensor, MeasurementConfig]:
    """A re-projection request: 8 particles around a true pose, its image, a reference 1 cm off."""
    truth = world.sample_camera_pose(generator)
    poses = (truth[None] @ se3_exp(0.01 * torch.randn(8, 6, generator=generator, dtype=torch.float64))).float()
    image = world.render_image(truth)
    pixels = (image * 255).round().to(torch.uint8).numpy()
    measurement = MeasurementConfig(pixels=16, warp=WarpConfig(max_spread=0.1, pixels=64, stride=4))
    reference_pose = truth @ se3_exp(torch.tensor([[0.0, 0.0, 0.0, 0.01, 0.0, 0.0]], dtype=torch.float64))[0]
    request, *_ = _request(world, generator, count=8)
    request = request.model_copy(
        update={
            "poses": poses.reshape(8, 16).tolist(),
            "warp": WarpRequest(reference_pose=reference_pose.tolist(), seed=7, measurement=measurement, image=pixels.tobytes()),
        }
    )
    return request, poses, torch.from_numpy(pixels).float() / 255.0, measurement


def test_worker_warps_as_the_in_process_localizer_does(world, generator):
    """A re-projection request is scored as :func:`warp_log_likelihoods` scores it in process with the
    same seed (so every shard of an update draws the same reference pixels); a map without surfaces
    renders the request's pixels instead; a warp image of the wrong size is refused when decoded."""
    request, poses, image, measurement = _warp_request(world, generator)
    result = NerfWorker(world, "w").handle(request)
    reference = render_reference(
        world.render_surface,
        torch.tensor(request.warp.reference_pose, dtype=torch.float64),
        world.default_intrinsics,
        measurement,
        torch.Generator().manual_seed(7),
    )
    expected = warp_log_likelihoods(poses, reference, image, world.default_intrinsics)
    torch.testing.assert_close(torch.tensor(result.log_likelihoods, dtype=torch.float64), expected)
    assert NerfWorker(world, "again").handle(request).log_likelihoods == result.log_likelihoods
    assert decode(encode(request), UpdateRequest) == request  # the image travels as msgpack bytes

    class RenderOnly:  # the world without its surface renderer, as an MLP or NDC map
        def __init__(self) -> None:
            self.render_rays, self.device, self.normalization, self.checksum = world.render_rays, world.device, world.normalization, world.checksum

    rendered = NerfWorker(RenderOnly(), "w").handle(request)
    pixels, colours = torch.tensor(request.pixels), torch.tensor(request.observed_rgb)
    torch.testing.assert_close(
        torch.tensor(rendered.log_likelihoods, dtype=torch.float64),
        particle_log_likelihoods(poses, pixels, colours, world.default_intrinsics, world.render_rays),
    )
    with pytest.raises(ValueError, match=r"warp image of 10 bytes, expected 57600 for 160×120×3"):
        UpdateRequest.model_validate(request.model_dump() | {"warp": request.warp.model_dump() | {"image": bytes(10)}})
    with pytest.raises(ValueError, match=r"measurement.warp is None"):
        WarpRequest.model_validate(request.warp.model_dump() | {"measurement": {}})


@dataclasses.dataclass(frozen=True)
class RgbdRequests:
    """An RGB-D update of :func:`_warp_request`'s particles: the request, its rendering and re-projection forms with one
    depth part, and what they were made from."""

    request: UpdateRequest
    rendered: UpdateRequest
    warped: UpdateRequest
    poses: torch.Tensor
    image: torch.Tensor
    measurement: MeasurementConfig
    truth: torch.Tensor
    observation: DepthObservation
    pixels: torch.Tensor


def _rgbd_requests(world: ProceduralWorld, generator: torch.Generator, depth_config: DepthConfig, offset: list[list[float]] | None = None) -> RgbdRequests:
    """The depth image a 40×30 depth camera (at the reference pose times ``offset``) sees, as the depth part of the re-projection request."""
    camera = PinholeIntrinsics.from_fov(40, 30, math.radians(60))
    request, poses, image, measurement = _warp_request(world, generator)
    truth = torch.tensor(request.warp.reference_pose, dtype=torch.float64)
    depth_pose = truth if offset is None else truth @ torch.tensor(offset, dtype=torch.float64)
    millimetres = depth_millimetres(render_depth_image(world.render_surface, depth_pose, camera).depth)
    observation = depth_observation(millimetres, camera, scale=1.0, T_cam_depth=offset)
    measurement = measurement.model_copy(update={"depth": depth_config})
    pixels = sample_depth_pixels(observation, depth_config, generator)
    depth_part = DepthRequest(image=millimetres.astype("<u2").tobytes(), intrinsics=camera, T_cam_depth=offset, measurement=measurement, pixels=pixels.tolist())
    rendered = request.model_copy(update={"warp": None, "depth": depth_part})
    warped = request.model_copy(update={"warp": request.warp.model_copy(update={"measurement": measurement}), "depth": depth_part})
    return RgbdRequests(request, rendered, warped, poses, image, measurement, truth, observation, pixels)


DEPTH_OFFSET = make_pose(so3_exp(torch.tensor([0.17, 0.0, 0.05], dtype=torch.float64)), torch.tensor([0.03, 0.01, -0.02], dtype=torch.float64)).tolist()
"""A depth camera turned 10 degrees and a few centimetres away from the colour camera (an exaggerated offset)."""


@pytest.mark.parametrize("offset", [None, DEPTH_OFFSET], ids=["at the colour camera", "offset"])
def test_worker_adds_the_depth_term_of_an_rgbd_request_as_the_localizer_does(world, generator, offset):
    """The depth term joins the colour term: rendered from every pose for the request's depth pixels, or
    re-projected from the reference render's depth points (the same seed, so the same on every shard),
    with the depth camera where the request's T_cam_depth puts it; the request decodes to itself; a map
    without surfaces leaves the term out; bad depth parts are refused."""
    depth_config = DepthConfig(pixels=20)
    case = _rgbd_requests(world, generator, depth_config, offset)
    poses, observation, depth_part = case.poses, case.observation, case.rendered.depth
    for message in (case.rendered, case.warped):
        assert decode(encode(message), UpdateRequest) == message

    colour = particle_log_likelihoods(
        poses, torch.tensor(case.request.pixels), torch.tensor(case.request.observed_rgb), world.default_intrinsics, world.render_rays
    )
    expected = colour.double() + rendered_depth_log_likelihoods(poses, observation, case.pixels, world.render_surface, depth_config).double()
    torch.testing.assert_close(torch.tensor(NerfWorker(world, "w").handle(case.rendered).log_likelihoods, dtype=torch.float64), expected)

    generator = torch.Generator().manual_seed(7)
    reference = render_reference(
        world.render_surface,
        case.truth,
        world.default_intrinsics,
        case.measurement,
        generator,
        depth_config.pixels,
        observation.intrinsics,
        observation.T_cam_depth,
    )
    assert reference.depth_points.shape == (depth_config.pixels, 4)
    expected = warp_log_likelihoods(poses, reference, case.image, world.default_intrinsics).double()
    expected = expected + warped_depth_log_likelihoods(poses, reference.depth_points, observation, depth_config).double()
    torch.testing.assert_close(torch.tensor(NerfWorker(world, "w").handle(case.warped).log_likelihoods, dtype=torch.float64), expected)

    class RenderOnly:  # the world without its surface renderer, as an MLP or NDC map
        def __init__(self) -> None:
            self.render_rays, self.device, self.normalization, self.checksum = world.render_rays, world.device, world.normalization, world.checksum

    torch.testing.assert_close(torch.tensor(NerfWorker(RenderOnly(), "w").handle(case.rendered).log_likelihoods, dtype=torch.float64), colour.double())
    with pytest.raises(ValueError, match=r"depth request: image of 10 bytes, expected 2400 for 40×30 uint16"):
        DepthRequest.model_validate(depth_part.model_dump() | {"image": bytes(10)})
    with pytest.raises(ValueError, match=r"expected 1 or more pixels \(u, v\) inside the 40×30 depth image"):
        DepthRequest.model_validate(depth_part.model_dump() | {"pixels": [[40.0, 0.0]]})
    with pytest.raises(ValueError, match=r"measurement.depth is None"):
        DepthRequest.model_validate(depth_part.model_dump() | {"measurement": {}})


def test_worker_looks_the_depth_term_up_in_its_maps_surface_distance_layer(world, generator):
    """``likelihood = "surface_distance"``: the worker adds the same term as the localizer computes in process, on the
    rendering and the re-projection path alike (the request's depth pixels, never the reference's depth points);
    its map without a layer refuses the request as a bad request naming why."""
    depth_config = DepthConfig(pixels=20, likelihood="surface_distance")
    case = _rgbd_requests(world, generator, depth_config)
    request, poses, observation, truth = case.request, case.poses, case.observation, case.truth
    layer = SurfaceDistance.from_points(depth_points(observation.depth[None], truth[None], observation.intrinsics), SurfaceDistanceConfig())

    class WorldWithLayer:  # the world as a map built from depth images
        def __init__(self) -> None:
            self.render_rays, self.render_surface, self.device, self.normalization = world.render_rays, world.render_surface, world.device, world.normalization
            self.surface_distance, self.checksum = layer, world.checksum

    worker = NerfWorker(WorldWithLayer(), "w")
    depth_term = surface_distance_log_likelihoods(poses, observation, case.pixels, layer, depth_config).double()
    colour = particle_log_likelihoods(poses, torch.tensor(request.pixels), torch.tensor(request.observed_rgb), world.default_intrinsics, world.render_rays)
    torch.testing.assert_close(torch.tensor(worker.handle(case.rendered).log_likelihoods, dtype=torch.float64), colour.double() + depth_term)
    reference = render_reference(world.render_surface, truth, world.default_intrinsics, case.measurement, torch.Generator().manual_seed(7))
    warped_colour = warp_log_likelihoods(poses, reference, case.image, world.default_intrinsics).double()
    torch.testing.assert_close(torch.tensor(worker.handle(case.warped).log_likelihoods, dtype=torch.float64), warped_colour + depth_term)
    with pytest.raises(RequestError, match="this worker's map has no surface-distance layer"):
        NerfWorker(world, "w").handle(case.rendered)
