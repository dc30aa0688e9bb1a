"""Similarity fits, scale sources and their checks, and the picking of video frames (no SfM run: fast)."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.posed_images import PosedImages
from locnerf.data.trajectory_files import read_trajectory, write_tum
from locnerf.errors import DatasetError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, so3_exp
from locnerf.geometry.similarity import Similarity, fit_similarity, fit_similarity_to_poses
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sfm.alignment import aligned_normalization, alignment_errors
from locnerf.sfm.metric import ScaleEstimate, agreed_scale, fit_to_trajectory, rotation_to_z_up, scale_from_depth
from locnerf.sfm.video import VideoSelection, select_video_frames, sharpness


def _random_similarity(generator: np.random.Generator) -> Similarity:
    rotation = so3_exp(torch.from_numpy(generator.normal(size=3))).numpy()
    return Similarity(float(generator.uniform(0.2, 5.0)), rotation, generator.normal(size=3) * 3)


def test_similarity_fits_recover_a_known_transform():
    generator = np.random.default_rng(0)
    truth = _random_similarity(generator)
    poses = np.stack([make_pose(so3_exp(torch.from_numpy(generator.normal(size=3))), torch.from_numpy(generator.normal(size=3))).numpy() for _ in range(20)])
    moved = truth.poses(poses)
    for fitted in (fit_similarity(poses[:, :3, 3], moved[:, :3, 3]), fit_similarity_to_poses(poses, moved)):
        assert fitted.scale == pytest.approx(truth.scale, rel=1e-10)
        np.testing.assert_allclose(fitted.rotation, truth.rotation, atol=1e-10)
        np.testing.assert_allclose(fitted.translation, truth.translation, atol=1e-9)
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        fit_similarity(line, line)


def test_depth_scale_names_disagreeing_images_and_refuses_drift(caplog):
    ratios = {f"frame{k}": 0.5 * (1 + 0.01 * np.sin(k)) for k in range(20)}
    ratios["frame7"] = 0.6
    with caplog.at_level(logging.WARNING):
        estimate = scale_from_depth(ratios)
    assert estimate.value == pytest.approx(0.5, rel=0.01) and estimate.detail["images_off"] == ["frame7"]
    assert "frame7 (+" in caplog.text
    drifting = {f"frame{k}": 0.5 * (1 + 0.02 * k) for k in range(20)}
    with pytest.raises(DatasetError, match=r"images disagree with the median scale .* drifts"):
        scale_from_depth(drifting)
    with pytest.raises(DatasetError, match="no image has"):
        scale_from_depth({})
    assert agreed_scale([ScaleEstimate(1.0, "user"), ScaleEstimate(1.04, "depth")]).source == "user"


def test_trajectory_fit_gives_scale_and_frame(tmp_path):
    generator = np.random.default_rng(1)
    truth = _random_similarity(generator)
    stamps = np.linspace(10.0, 20.0, 101)
    positions = np.stack((np.cos(stamps), np.sin(1.3 * stamps), 0.2 * stamps), axis=1)
    poses = torch.eye(4, dtype=torch.float64).repeat(len(stamps), 1, 1)
    poses[:, :3, 3] = torch.from_numpy(truth.points(positions))
    path = write_tum(tmp_path / "vio.txt", stamps, poses)
    image_stamps = stamps[5:95:3] + 0.03  # between trajectory samples: interpolated
    centres = np.stack((np.cos(image_stamps), np.sin(1.3 * image_stamps), 0.2 * image_stamps), axis=1)
    fitted, detail = fit_to_trajectory(centres, image_stamps, read_trajectory(path))
    assert fitted.scale == pytest.approx(truth.scale, rel=2e-3) and detail["images"] == len(image_stamps)
    with pytest.raises(DatasetError, match="never overlap"):
        fit_to_trajectory(centres, image_stamps + 100.0, read_trajectory(path))


def test_rotation_to_z_up():
    for up in (np.array([0.0, -1.0, 0.0]), np.array([0.3, 0.2, -0.9]), np.array([0.0, 0.0, -1.0])):
        rotation = rotation_to_z_up(up)
        np.testing.assert_allclose(rotation @ (up / np.linalg.norm(up)), [0.0, 0.0, 1.0], atol=1e-12)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)


def test_video_frames_are_sharp_and_spaced_by_motion(tmp_path):
    generator = np.random.default_rng(2)
    noise = generator.random((240, 1200)).astype(np.float32)  # blobs and finer detail, as a wall seen by a camera
    texture = cv2.normalize(4.2 * cv2.GaussianBlur(noise, (0, 0), 8.0) + 0.6 * cv2.GaussianBlur(noise, (0, 0), 2.0), None, 0, 255, cv2.NORM_MINMAX)
    texture = cv2.cvtColor(texture.astype(np.uint8), cv2.COLOR_GRAY2BGR)
    path = tmp_path / "pan.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (320, 240))
    blurred = set(range(3, 60, 4))
    for k in range(60):
        frame = texture[:, 10 * k : 10 * k + 320]
        writer.write(cv2.blur(frame, (15, 15)) if k in blurred else frame)
    writer.release()
    picked = select_video_frames(path, tmp_path / "frames", VideoSelection(motion=0.1, window=3))
    assert picked.numbers and not set(picked.numbers) & blurred
    steps = np.diff(picked.numbers)
    assert steps.min() >= 3 and steps.max() <= 6  # 0.1 of 160 px thumbnails = 32 px of 320: 3.2 frames at 10 px per frame
    assert all(p.is_file() for p in picked.paths) and picked.stamps[1] == pytest.approx(picked.numbers[1] / 30.0)
    assert sharpness(cv2.imread(str(picked.paths[0]), cv2.IMREAD_GRAYSCALE)) > 0


def test_aligned_normalization_takes_true_poses_into_the_map_frame():
    generator = np.random.default_rng(3)
    map_to_truth = _random_similarity(generator)
    map_poses = np.stack([make_pose(so3_exp(torch.from_numpy(generator.normal(size=3))), torch.from_numpy(generator.normal(size=3))).numpy() for _ in range(6)])
    truth = map_to_truth.poses(map_poses)
    fitted, report = alignment_errors(map_poses, truth)
    assert report["summary"]["translation_max_m"] < 1e-9 and report["summary"]["rotation_max_deg"] < 1e-5
    normalization = aligned_normalization(MapNormalization(), fitted)
    np.testing.assert_allclose(normalization.metric_to_map(torch.from_numpy(truth)).numpy(), map_poses, atol=1e-9)
    np.testing.assert_allclose(normalization.map_to_metric(torch.from_numpy(map_poses)).numpy(), truth, atol=1e-9)


def test_ground_truth_frames_are_read_into_an_aligned_maps_frame():
    """The eval commands' frames (PosedImages in the data set's frame) re-expressed in an aligned SfM map's frame
    (:meth:`PosedImages.in_frame`): poses by the inverse similarity, depths and bounds in the map's units."""
    generator = np.random.default_rng(5)
    map_to_truth = _random_similarity(generator)
    map_poses = np.stack([make_pose(so3_exp(torch.from_numpy(generator.normal(size=3))), torch.from_numpy(generator.normal(size=3))).numpy() for _ in range(4)])
    camera = PinholeIntrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12)
    depths = torch.from_numpy(generator.uniform(0.5, 3.0, size=(4, 6, 8)))
    offset = make_pose(so3_exp(torch.tensor([0.0, 0.01, 0.0], dtype=torch.float64)), torch.tensor([0.03, 0.0, 0.0], dtype=torch.float64))
    truth_frames = PosedImages(
        images=torch.zeros(4, 12, 16, 3),
        T_world_cam=torch.from_numpy(map_to_truth.poses(map_poses)),
        intrinsics=camera,
        near=0.1,
        far=8.0,
        normalization=MapNormalization(),
        names=[f"frame-{i}" for i in range(4)],
        scene_bounds=torch.tensor([[-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]], dtype=torch.float64),
        depths=depths,
        depth_intrinsics=camera.scaled(0.5),
        T_cam_depth=offset,
    )
    aligned = aligned_normalization(MapNormalization(), map_to_truth)
    in_map = truth_frames.in_frame(aligned)
    np.testing.assert_allclose(in_map.T_world_cam.numpy(), map_poses, atol=1e-9)
    units = 1.0 / map_to_truth.scale
    np.testing.assert_allclose(in_map.depths.numpy(), depths.numpy() * units, rtol=1e-12)
    assert in_map.near == pytest.approx(0.1 * units) and in_map.far == pytest.approx(8.0 * units)
    np.testing.assert_allclose(in_map.T_cam_depth[:3, 3].numpy(), offset[:3, 3].numpy() * units, rtol=1e-12)
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-2.0, 2.0) for z in (-3.0, 3.0)])
    moved = (corners - map_to_truth.translation) @ map_to_truth.rotation / map_to_truth.scale
    np.testing.assert_allclose(in_map.scene_bounds.numpy(), np.stack((moved.min(0), moved.max(0))), atol=1e-9)
    assert in_map.normalization == aligned and truth_frames.in_frame(MapNormalization()) is truth_frames
    with pytest.raises(DatasetError, match="NDC"):
        truth_frames.in_frame(aligned.model_copy(update={"ndc": True}))


def test_alignment_through_a_readers_own_normalization_and_between_ndc_frames():
    """A ground truth read in a normalised frame (LLFF's: scaled and recentred, NDC rays) and a forward-facing SfM map:
    the aligned normalization composes the reader's with the fitted similarity, NDC frames move into each other
    (bounds: the target's), views move with their start offsets, and errors are scored in the truth's units."""
    from locnerf.data.posed_images import frame_change
    from locnerf.eval.real_data import View, in_truth_units, view_in_frame
    from locnerf.eval.single_image import TrialResult

    generator = np.random.default_rng(11)
    map_to_truth = _random_similarity(generator)
    reader = MapNormalization(T_map_dataset=_random_similarity(generator).poses(np.eye(4)[None])[0].tolist(), scale=0.3, ndc=True, near=1.2, far=9.0)
    map_frame = MapNormalization(ndc=True, near=0.9, far=5.0)
    map_poses = np.stack([make_pose(so3_exp(torch.from_numpy(generator.normal(size=3))), torch.from_numpy(generator.normal(size=3))).numpy() for _ in range(3)])
    truth = torch.from_numpy(map_to_truth.poses(map_poses))
    aligned = aligned_normalization(map_frame, map_to_truth, reader)
    assert (aligned.ndc, aligned.near, aligned.far) == (True, 0.9, 5.0)
    move = frame_change(reader, aligned)
    np.testing.assert_allclose(move(truth).numpy(), map_poses, atol=1e-9)
    frames = PosedImages(
        images=torch.zeros(3, 4, 4, 3),
        T_world_cam=truth,
        intrinsics=PinholeIntrinsics.centred(4.0, 4.0, 4, 4),
        near=1.2,
        far=9.0,
        normalization=reader,
        names=["a", "b", "c"],
        scene_bounds=torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64),
    )
    in_map = frames.in_frame(aligned)
    np.testing.assert_allclose(in_map.T_world_cam.numpy(), map_poses, atol=1e-9)
    assert (in_map.near, in_map.far) == (0.9, 5.0) and torch.equal(in_map.scene_bounds, frames.scene_bounds)
    offset = torch.tensor([0.05, -0.02, 0.01], dtype=torch.float64)
    view = view_in_frame(View(7, "a", truth[0], frames.images[0], False, offset), move)
    np.testing.assert_allclose(view.truth.numpy(), map_poses[0], atol=1e-9)
    expected = map_to_truth.rotation.T @ offset.numpy() / map_to_truth.scale  # a displacement: rotated and scaled, not shifted
    np.testing.assert_allclose(view.offset.numpy(), expected, atol=1e-9)
    units = aligned.scale / reader.scale
    assert units == pytest.approx(1.0 / map_to_truth.scale)
    scored = in_truth_units(TrialResult(0.2, 1.0, 0.0, 0, history_translation=[0.4, 0.2]), units)
    assert scored.translation_error == pytest.approx(0.2 * map_to_truth.scale) and scored.history_translation[0] == pytest.approx(0.4 * map_to_truth.scale)


def test_up_from_level_cameras_whatever_their_pitch():
    """Cameras without roll, pitched 30 degrees down, turning +-20 degrees: the up axis perpendicular to their x axes is
    the true one (the mean of their up axes is 30 degrees off); cameras that do not turn fall back to that mean, in the
    plane perpendicular to their common x axis."""
    from locnerf.sfm.metric import level_camera_up

    world_up = np.array([0.2, -0.3, 0.93])
    world_up /= np.linalg.norm(world_up)
    to_world = rotation_to_z_up(world_up).T  # a frame whose +z is world_up

    def cameras(yaws_deg):
        poses = []
        for yaw in np.radians(yaws_deg):
            # OpenCV camera: x right (horizontal), y down, z forward; level camera pitched 30 degrees down
            forward = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * np.cos(np.radians(30)) + np.array([0, 0, -np.sin(np.radians(30))])
            right = np.cross(forward, [0.0, 0.0, 1.0])
            right /= np.linalg.norm(right)
            pose = np.eye(4)
            pose[:3, :3] = to_world @ np.stack((right, np.cross(forward, right), forward), axis=1)
            poses.append(pose)
        return np.stack(poses)

    up, source = level_camera_up(cameras(np.linspace(-20, 20, 9)))
    assert source == "level_cameras" and np.degrees(np.arccos(np.clip(up @ world_up, -1, 1))) < 1e-4
    still, source = level_camera_up(cameras(np.zeros(5)))
    assert source == "camera_mean" and np.degrees(np.arccos(np.clip(still @ world_up, -1, 1))) == pytest.approx(30.0, abs=1e-6)
