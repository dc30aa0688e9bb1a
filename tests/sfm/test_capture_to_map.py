"""The whole capture-to-map path with real pycolmap on a small RGB-D capture of the procedural world, and its bad inputs.

The capture (12 frames, 240×180, exact depth) is rendered once per module; structure from motion on it
takes about 15 s on 2 cores. Poses are scored against the rendering poses after one similarity fit.
"""

from __future__ import annotations

import json
import logging
import shutil

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.colour_camera import colour_camera_of
from locnerf.data.llff import NDC_CUBE, read_llff
from locnerf.data.map_lens import map_lens
from locnerf.errors import ConfigError, DatasetError, LocnerfInputError
from locnerf.field.grid import GridFieldConfig
from locnerf.field.map_file import load_map, save_map
from locnerf.field.map_info import METRIC_FRAME_KEY, metric_frame_problem
from locnerf.geometry import pose_inverse
from locnerf.geometry.similarity import fit_similarity_to_poses
from locnerf.sfm.alignment import aligned_normalization, alignment_errors
from locnerf.sfm.capture import read_capture
from locnerf.sfm.depth_camera import METADATA_RECORD as DEPTH_RECORD
from locnerf.sfm.pipeline import MetricOptions, posed_capture
from locnerf.sfm.reconstruct import SfmConfig
from locnerf.train import BuildConfig, build_map
from locnerf_cli.main import main
from tests.sfm.world_capture import CAMERA, FRAMES, write_world_capture

pytest.importorskip("pycolmap")

TINY_BUILD = BuildConfig(steps=3, field=GridFieldConfig(voxels=24**3), surface_distance=None, threads=1)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """(capture folder, cache folder, true poses (K, 4, 4)) of the world's RGB-D capture."""
    root = tmp_path_factory.mktemp("world_capture")
    truth = write_world_capture(root / "capture")
    return root / "capture", root / "cache", truth


def _scored(images, truth: torch.Tensor) -> dict:
    return alignment_errors(images.T_world_cam.double().numpy(), truth.numpy()[images.indices])[1]["summary"]


def test_rgbd_capture_to_a_metric_map_and_its_cache(capture, tmp_path):
    folder, cache, truth = capture
    images, metadata = posed_capture(folder, cache, depth_camera="points")
    assert metadata["sfm"]["posed"] == FRAMES and not metadata["sfm"]["unregistered"] and not metadata["sfm"]["cached"]
    frame = metadata[METRIC_FRAME_KEY]
    assert frame["metric"] and frame["scale"]["source"] == "depth" and frame["gravity"]["source"] == "level_cameras"
    summary = _scored(images, truth)
    # metric from depth: the fitted similarity to the true (metric) poses has scale 1 within 1 %
    assert abs(summary["scale_map_to_truth"] - 1.0) < 0.01
    assert summary["translation_max_m"] < 0.01 and summary["rotation_max_deg"] < 0.5
    # up from level cameras (no roll; they pitch by -9..-1 degrees and turn +-15): the map's +z is the world's up (+y) within 1 degree
    map_up_in_world = fit_similarity_to_poses(images.T_world_cam.double().numpy(), truth.numpy()[images.indices]).rotation @ np.array([0.0, 0.0, 1.0])
    assert map_up_in_world[1] > np.cos(np.radians(1.0))
    # the depth images were rendered from the colour camera: the calibrated depth camera sits there (within 3 mm, 0.2 degrees)
    assert images.depths is not None and float(images.T_cam_depth[:3, 3].norm()) < 0.003
    assert metadata[DEPTH_RECORD]["rotation_deg"] < 0.2 and metadata[DEPTH_RECORD]["residual_after_m"] < 0.003
    torch.testing.assert_close(pose_inverse(colour_camera_of(metadata)), images.T_cam_depth)

    radiance_map = build_map(images, TINY_BUILD)
    radiance_map.metadata.update(metadata)
    path = save_map(radiance_map, tmp_path / "world_sfm.locmap")
    loaded = load_map(path, "cpu")
    assert loaded.metadata[METRIC_FRAME_KEY]["metric"] and metric_frame_problem(loaded.metadata) is None
    recorded = map_lens(loaded)  # the SfM camera, which query images are resampled through (locnerf.data.map_lens)
    lens, distortion = recorded.lens, np.asarray(recorded.distortion)
    assert (lens.width, lens.height) == (240, 180) and distortion.shape == (4,)
    assert loaded.default_intrinsics.fx == pytest.approx(lens.fx / 4)

    again, metadata_again = posed_capture(folder, cache)
    assert metadata_again["sfm"]["cached"] and torch.allclose(again.T_world_cam, images.T_world_cam)


def test_known_distance_agrees_with_depth_and_a_wrong_scale_is_refused(capture):
    folder, cache, truth = capture
    metres = float(torch.linalg.vector_norm(truth[0, :3, 3] - truth[FRAMES - 1, :3, 3]))
    images, metadata = posed_capture(folder, cache, MetricOptions(known_distance=("frame-000000", str(FRAMES - 1), metres)))
    sources = {s["source"]: s["metres_per_sfm_unit"] for s in metadata[METRIC_FRAME_KEY]["scale_sources"]}
    assert metadata[METRIC_FRAME_KEY]["scale"]["source"] == "known_distance"
    assert abs(sources["known_distance"] / sources["depth"] - 1.0) < 0.01
    assert abs(_scored(images, truth)["scale_map_to_truth"] - 1.0) < 0.01
    with pytest.raises(LocnerfInputError, match=r"scale sources disagree: user .* depth .*more than 5 %"):
        posed_capture(folder, cache, MetricOptions(scale=1.1 * sources["depth"]))
    with pytest.raises(LocnerfInputError, match="frame 'frame-000099' has no pose"):
        posed_capture(folder, cache, MetricOptions(known_distance=("frame-000099", "0", 1.0)))


def test_images_without_scale_make_a_non_metric_map_the_filter_refuses(capture, tmp_path, caplog):
    folder, _, _ = capture
    plain = tmp_path / "images"
    plain.mkdir()
    for k, image in enumerate(sorted((folder / "seq-01").glob("*.color.png"))):
        shutil.copy(image, plain / f"image{k:03d}.png")
    cv2.imwrite(str(plain / "image900_blank.png"), np.full((180, 240, 3), 128, np.uint8))
    with caplog.at_level(logging.WARNING):
        images, metadata = posed_capture(plain, tmp_path / "cache")
    assert "image900_blank.png" in metadata["sfm"]["unregistered"]
    assert "no SIFT features" in metadata["sfm"]["unregistered"]["image900_blank.png"]
    assert "image900_blank.png: no SIFT features" in caplog.text
    assert len(images) == FRAMES and images.depths is None
    assert not metadata[METRIC_FRAME_KEY]["metric"]

    radiance_map = build_map(images, TINY_BUILD)
    radiance_map.metadata.update(metadata)
    path = save_map(radiance_map, tmp_path / "non_metric.locmap")
    from locnerf_services.filter_loop.__main__ import FilterProcessConfig, build_loop

    with pytest.raises(ConfigError, match="without a metric scale.*--known-distance"):
        build_loop(FilterProcessConfig(map=str(path), device="cpu"))


def test_bad_captures_are_refused_by_name(tmp_path):
    few = tmp_path / "few"
    few.mkdir()
    for k in range(2):
        cv2.imwrite(str(few / f"{k}.png"), np.zeros((20, 30, 3), np.uint8))
    with pytest.raises(DatasetError, match="2 images, expected at least 3"):
        read_capture(few, tmp_path / "work")
    cv2.imwrite(str(few / "2.png"), np.zeros((20, 31, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"1 images differ in size from 0.png \(30x20\): 2.png \(31x20\)"):
        read_capture(few, tmp_path / "work")
    broken = tmp_path / "walk.mp4"
    broken.write_bytes(b"not a video at all" * 100)
    with pytest.raises(DatasetError, match="walk.mp4: cannot be opened"):
        read_capture(broken, tmp_path / "work")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="no images"):
        read_capture(empty, tmp_path / "work")


def test_map_build_sfm_command_reuses_the_cached_reconstruction(capture, tmp_path, capsys):
    folder, cache, _ = capture
    out = tmp_path / "cli.locmap"
    posed_capture(folder, cache)  # the reconstruction the command finds in its cache
    assert main(["map", "build", str(folder), "--sfm", "--sfm-cache", str(cache), "--steps", "2", "--voxels", str(24**3), "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["sfm"]["cached"] and printed[METRIC_FRAME_KEY]["metric"] and len(printed["sfm"]["frames"]) == FRAMES
    assert load_map(out, "cpu").metadata[METRIC_FRAME_KEY]["scale"]["source"] == "depth"


def test_an_existing_colmap_model_is_taken_as_it_is(capture, tmp_path):
    folder, cache, truth = capture
    images, metadata = posed_capture(folder, cache)
    model = tmp_path / "project"
    shutil.copytree(metadata["sfm"]["model"], model / "sparse" / "0")
    shutil.copytree(folder, model / "images")
    again, again_metadata = posed_capture(
        model, tmp_path / "unused", MetricOptions(depth=False, scale=metadata[METRIC_FRAME_KEY]["scale"]["metres_per_sfm_unit"])
    )
    assert again_metadata["sfm"]["kind"] == "colmap" and again_metadata[METRIC_FRAME_KEY]["scale"]["source"] == "user"
    assert len(again) == FRAMES and not (tmp_path / "unused").exists()
    torch.testing.assert_close(again.T_world_cam, images.T_world_cam, atol=1e-9, rtol=0)


def test_an_llff_folder_alone_makes_a_forward_facing_map_that_aligns_to_its_poses(tmp_path):
    """An LLFF folder (images_8/, and a poses_bounds.npy of the true poses that the build does not read): the SfM poses go
    into nerf-pytorch's NDC frame with bounds from the SfM points' depths (the smallest near bound is 1/0.75 map units);
    after one similarity fitted on the cameras, the LLFF reader's frames land on the map's cameras (locnerf eval's path)."""
    folder = tmp_path / "llff"
    truth = write_world_capture(folder / "images_8", depth=False)
    gl = truth.numpy()
    raw = np.stack(
        (-gl[:, :3, 1], gl[:, :3, 0], gl[:, :3, 2], gl[:, :3, 3], np.tile([[180.0 * 8], [240.0 * 8], [CAMERA.fx * 8]], (len(gl), 1, 1))[..., 0]), axis=2
    )
    np.save(folder / "poses_bounds.npy", np.concatenate((raw.reshape(len(gl), 15), np.tile([0.5, 12.0], (len(gl), 1))), axis=1))
    metres = float(torch.linalg.vector_norm(truth[0, :3, 3] - truth[FRAMES - 1, :3, 3]))
    # One COLMAP thread: its seed then fixes the reconstruction (with two, the order of its threads' work varies, and one
    # suite run of 2026-11-28 posed a camera 23 degrees off).
    single_thread = SfmConfig(threads=1)
    images, metadata = posed_capture(folder, tmp_path / "cache", MetricOptions(known_distance=("image000", str(FRAMES - 1), metres)), single_thread)
    assert metadata["sfm"]["kind"] == "llff" and metadata["sfm"]["forward_facing"]["percentiles"] == [0.1, 99.9]
    assert images.normalization.ndc and torch.equal(images.scene_bounds, NDC_CUBE) and images.depths is None
    assert images.normalization.near == pytest.approx(0.9 / 0.75)
    # the SfM points' nearest depths are true surface depths of this room (metres, the known distance's scale)
    assert 0.3 < metadata["sfm"]["forward_facing"]["near_min"] < metadata["sfm"]["forward_facing"]["far_max"] < 15.0
    reader = read_llff(folder, downscale=8)
    similarity, report = alignment_errors(images.T_world_cam.double().numpy(), reader.T_world_cam.double().numpy())
    assert report["summary"]["rotation_max_deg"] < 0.5 and report["summary"]["translation_max_m"] < 0.01 * reader.normalization.scale
    in_map = reader.in_frame(aligned_normalization(images.normalization, similarity, reader.normalization))
    assert in_map.normalization.ndc and in_map.near == images.normalization.near
    gap = np.linalg.norm(in_map.T_world_cam[:, :3, 3].numpy() - images.T_world_cam[:, :3, 3].numpy(), axis=1)
    assert gap.max() == pytest.approx(report["summary"]["translation_max_m"] / similarity.scale, rel=1e-6)  # the fit's errors, in map units


def test_an_unknown_depth_camera_placement_is_refused(capture) -> None:
    folder, cache, _ = capture
    with pytest.raises(DatasetError, match=r"depth camera placement 'nowhere': expected one of colour, points, photometric"):
        posed_capture(folder, cache, depth_camera="nowhere")
