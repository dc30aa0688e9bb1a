"""The TUM RGB-D layout, on a small folder written here from the procedural world: association by stamp,
depth in 1/5000 m, poses from groundtruth.txt, and the folder used where 7-Scenes is (read_dataset,
the ingest's replay, ``locnerf odometry``)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from locnerf.data.detect import dataset_format, read_dataset
from locnerf.data.trajectory_files import read_trajectory, write_tum
from locnerf.data.tum_rgbd import associate, read_tum_rgbd
from locnerf.errors import DatasetError, LocnerfInputError
from locnerf.field.map_file import save_map
from locnerf.field.protocol import MapNormalization
from locnerf.filter.depth_measurement import render_depth_image
from locnerf.geometry import opengl_to_opencv, relative_pose, rotation_error_deg, se3_exp, translation_error
from locnerf.odometry.sequence import OdometrySourceConfig, RecordedReplay, sequence_rgbd_frames, sequence_track
from locnerf.odometry.tracks import OdometryTrack
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.events import ImageEvent
from locnerf.sim.paths import read_sequence_path
from locnerf.sim.scenario import ScenarioConfig, build_scenario, run_times
from locnerf.sim.world import ProceduralWorld
from locnerf_cli.main import main
from locnerf_services.sensor_ingest.__main__ import IngestConfig, sensor_events
from tests.field.test_grid_and_map_file import _tiny_map

CAMERA = PinholeIntrinsics.from_fov(160, 120, math.radians(60))
FRAMES = 9
T0 = 1305031102.175304


@pytest.fixture(scope="module")
def tum_folder(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, torch.Tensor]:
    """9 colour frames at 30 Hz; depth stamped 4-7 ms off (frame 4 25 ms off: no depth); ground truth at 100 Hz, OpenCV axes."""
    folder = tmp_path_factory.mktemp("tum")
    world = ProceduralWorld.default()
    start = world.sample_camera_pose(torch.Generator().manual_seed(2)).double()
    step = torch.tensor([0.004, -0.006, 0.003, 0.012, -0.004, -0.015], dtype=torch.float64) * 30  # per second
    pose_at = lambda t: start @ se3_exp(step * (t - T0))  # noqa: E731
    (folder / "rgb").mkdir()
    (folder / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images"], ["# depth maps"]
    for k in range(FRAMES):
        stamp = T0 + k / 30
        pose = pose_at(stamp)
        rgb = (world.render_image(pose.float(), CAMERA).clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()
        cv2.imwrite(str(folder / f"rgb/{stamp:.6f}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        rgb_lines.append(f"{stamp:.6f} rgb/{stamp:.6f}.png")
        depth_stamp = stamp + (0.025 if k == 4 else 0.004 + 0.001 * (k % 4))
        depth = render_depth_image(world.render_surface, pose, CAMERA).depth.double().numpy()
        cv2.imwrite(str(folder / f"depth/{depth_stamp:.6f}.png"), np.round(depth * 5000).astype(np.uint16))
        depth_lines.append(f"{depth_stamp:.6f} depth/{depth_stamp:.6f}.png")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    truth_stamps = T0 - 0.005 + np.arange(40) / 100
    write_tum(folder / "groundtruth.txt", truth_stamps, opengl_to_opencv(torch.stack([pose_at(t) for t in truth_stamps])))
    matrix = np.array([[CAMERA.fx, 0, CAMERA.cx], [0, CAMERA.fy, CAMERA.cy], [0, 0, 1]])
    np.savetxt(folder / "camera-intrinsics.txt", matrix)
    return folder, torch.stack([pose_at(T0 + k / 30) for k in range(FRAMES)])


def test_association_picks_the_nearest_depth_within_20_ms() -> None:
    assert associate(np.array([0.0, 0.1, 0.2, 0.3]), np.array([0.005, 0.09, 0.25, 0.31])).tolist() == [0, 1, -1, 3]


def test_frames_read_with_their_depth_and_ground_truth(tum_folder) -> None:
    folder, poses = tum_folder
    assert dataset_format(folder) == "tum_rgbd"
    frames = read_dataset(folder, split="all", downscale=1)
    kept = [k for k in range(FRAMES) if k != 4]  # frame 4's depth is 25 ms away
    assert frames.indices == kept and len(frames) == 8
    # Ground truth interpolated at each colour stamp (the 100 Hz samples straddle it), converted to OpenGL axes.
    assert float(translation_error(frames.T_world_cam, poses[kept]).max()) < 1e-6
    assert float(rotation_error_deg(frames.T_world_cam, poses[kept]).max()) < 1e-4
    expected = render_depth_image(ProceduralWorld.default().render_surface, poses[0], CAMERA).depth.double()
    assert torch.allclose(frames.depths[0].double(), expected, atol=0.5 / 5000 + 1e-6)  # 1/5000 m quantisation
    assert frames.intrinsics == CAMERA and frames.depth_intrinsics == CAMERA
    assert read_tum_rgbd(folder, "test", downscale=1).indices == [0]  # every 8th of the 8 associated frames
    assert len(read_tum_rgbd(folder, "train", downscale=2)) == 7


def test_the_ingest_replays_it_and_locnerf_odometry_tracks_it(tum_folder, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder, poses = tum_folder
    events = list(sensor_events(IngestConfig(source="replay", replay={"path": str(folder), "split": "all", "downscale": 1, "frame_rate": 30.0})))
    images = [e for e in events if isinstance(e, ImageEvent)]
    assert len(images) == 8 and images[0].depth is not None and images[0].depth.millimetres.dtype == np.uint16
    out = tmp_path / "odometry.txt"
    assert main(["odometry", str(folder), "--split", "all", "--downscale", "1", "--every", "1", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["poses"] == 8 and report["gaps"] == 0
    trajectory = read_trajectory(out)
    truth = relative_pose(poses[:1], poses[[k for k in range(FRAMES) if k != 4]])
    assert float(translation_error(trajectory.poses, truth).max()) < 0.005 and float(rotation_error_deg(trajectory.poses, truth).max()) < 0.2
    assert report["drift"]["ape_translation_max"] < 0.005
    noise = report["step_noise"]  # the per-step error between 8 tracked frames: 7 steps, millimetres and tenths of a degree
    assert noise["steps"] == 7 and max(noise["translation_sigma"]) < 0.005 and max(noise["rotation_sigma"]) < math.radians(0.4)


def test_locnerf_odometry_refuses_a_map_without_a_colour_camera(tum_folder, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``--map`` lends the odometry the colour camera's placement the map records; a map that records none is refused, named."""
    folder, _ = tum_folder
    plain = save_map(_tiny_map(torch.Generator().manual_seed(0)), tmp_path / "plain.locmap")
    assert main(["odometry", str(folder), "--split", "all", "--downscale", "1", "--map", str(plain), "--out", str(tmp_path / "o.txt")]) == 2
    assert f"--map {plain}: the map records no colour camera" in caplog.text and not (tmp_path / "o.txt").exists()


def test_a_malformed_list_is_refused_naming_file_and_line(tmp_path: Path) -> None:
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        (tmp_path / name).write_text("# header\n")
    (tmp_path / "rgb.txt").write_text("# header\n1.0 rgb/1.png\n0.5 rgb/0.png\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt, line 3: stamp 0\.5 is not after 1\.0"):
        read_tum_rgbd(tmp_path)
    (tmp_path / "rgb.txt").write_text("1.0\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt, line 1: '1\.0', expected 'stamp filename'"):
        read_tum_rgbd(tmp_path)


def _tracking_argv(folder: Path, out: Path, *extra: str) -> list[str]:
    return [
        "eval", "tracking", "--map", "world", "--sequence", str(folder), "--split", "all", "--downscale", "1", "--frame-rate", "30",
        "--image-rate", "15", "--duration", "0.2", "--init", "gaussian", "--preset", "llff", "--converged-hold", "0", "--converged-translation", "1", "--converged-rotation", "45", "--seed", "1", "--quiet", "--out", str(out), *extra,
    ]  # fmt: skip


def test_recorded_odometry_feeds_the_tracking_run_and_evo_reproduces_its_figure(tum_folder, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``locnerf odometry`` on the folder, then ``eval tracking --odometry FILE --out``: the report names the
    file, and evo's APE (no alignment: estimate and reference share the map's frame) on the written
    TUM files is the report's error at every scored stamp, its median the headline's."""
    from evo.core import metrics, sync
    from evo.tools import file_interface

    folder, _ = tum_folder
    odometry = tmp_path / "odometry_in.txt"
    assert main(["odometry", str(folder), "--split", "all", "--downscale", "1", "--out", str(odometry)]) == 0
    capsys.readouterr()
    assert main([*_tracking_argv(folder, tmp_path / "run", "--odometry", str(odometry)), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["odometry"] == "file:odometry_in.txt" and report["odometry_report"]["gaps"] == 0
    assert report["odometry_drift"]["ape_translation_max"] < 0.005  # the file is the RGB-D odometry of exact renders
    written = json.loads((tmp_path / "run" / "tracking.json").read_text())["trajectories"]
    assert written["estimate"].endswith("estimate.txt") and Path(written["drift_plot"]).stat().st_size > 0
    reference = file_interface.read_tum_trajectory_file(str(tmp_path / "run" / "reference.txt"))
    estimate = file_interface.read_tum_trajectory_file(str(tmp_path / "run" / "estimate.txt"))
    reference, estimate = sync.associate_trajectories(reference, estimate, max_diff=1e-6)
    ours = report["series"]
    first = ours["stamps"].index(float(estimate.timestamps[0]))
    for relation, series, headline in (
        (metrics.PoseRelation.translation_part, "translation_error", "translation_median"),
        (metrics.PoseRelation.rotation_angle_deg, "rotation_error_deg", "rotation_median_deg"),
    ):
        ape = metrics.APE(relation)
        ape.process_data((reference, estimate))
        assert np.allclose(ape.error, ours[series][first:], atol=1e-6)
        lower_median = float(np.sort(ape.error)[(len(ape.error) - 1) // 2])  # the headline's median: the lower middle value
        assert lower_median == pytest.approx(report["start"]["after_convergence"][headline], abs=1e-6)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("0.0 0 0 0 0 0 0 1\n0.2 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n", r"bad\.txt, line 3: stamp 0\.1 s is before line 2's 0\.2 s"),
        ("0.0 0 0 0 0 0 0 1\n0.0 0 0 0 0 0 0 1\n", r"bad\.txt, line 2: stamp 0\.0 s is a duplicate of line 1's"),
        ("0.0 0 0 0 0 0 0.5 1\n", r"bad\.txt, line 1: quaternion .* has norm 1\.118034; expected a unit quaternion"),
        (
            "100.0 0 0 0 0 0 0 1\n100.1 0 0 0 0 0 0 1\n",
            r"bad\.txt: stamps 100\.000000–100\.100000 s \(lines 1–2\) never overlap the images' stamps 0\.000000–0\.2",
        ),
    ],
)
def test_bad_odometry_files_are_refused_by_the_command(tum_folder, tmp_path: Path, content: str, message: str, caplog: pytest.LogCaptureFixture) -> None:
    folder, _ = tum_folder
    (tmp_path / "bad.txt").write_text(content)
    assert main(_tracking_argv(folder, tmp_path / "run", "--odometry", str(tmp_path / "bad.txt"))) == 2
    assert re.search(message, caplog.text), message


def test_a_non_rigid_extrinsic_is_refused(tum_folder, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    folder, _ = tum_folder
    odometry = write_tum(tmp_path / "odometry.txt", np.arange(5) / 15, torch.eye(4, dtype=torch.float64).repeat(5, 1, 1))
    np.savetxt(tmp_path / "extrinsic.txt", np.diag([1.0, 1.0, 1.1, 1.0]))
    assert main(_tracking_argv(folder, tmp_path / "run", "--odometry", str(odometry), "--T-body-cam", str(tmp_path / "extrinsic.txt"))) == 2
    assert re.search(r"--T-body-cam .*extrinsic\.txt: expected a rigid transform", caplog.text), caplog.text


def test_a_kidnapped_camera_reaches_the_rgbd_odometry_but_a_recorded_file_is_refused(tum_folder, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A kidnapping moves the camera ahead along the path: the RGB-D odometry computed from the frames it delivers
    sees that jump (here a step of 5 frames in one stamp: a gap, then it resumes from the new frame), as a robot's own odometry would; a recorded
    trajectory follows the recorded camera, so a kidnapping with it is refused, by the library and by the command."""
    folder, poses = tum_folder
    path = read_sequence_path(folder, "all", 1, speed=1.0, odom_rate=30.0, frame_rate=30.0)
    config = ScenarioConfig(duration=0.1, image_rate=15.0, vio={"rate": 30.0}, kidnap_at=0.05, kidnap_shift=4 / 30)
    stamps, path_times = run_times(path, config)
    replay = RecordedReplay(path, folder, "all")
    assert torch.allclose(path_times * 30, torch.tensor([0.0, 1.0, 6.0, 7.0], dtype=torch.float64))
    camera = list(sequence_rgbd_frames(replay, stamps, path_times))
    sixth = next(sequence_rgbd_frames(replay, path_times[2:3]))
    assert [e.stamp for e in camera] == stamps.tolist() and np.array_equal(camera[2].frame.pixels, sixth.frame.pixels)
    assert not np.array_equal(camera[2].frame.pixels, next(sequence_rgbd_frames(replay, stamps[2:3])).frame.pixels)
    track = sequence_track(OdometrySourceConfig(source="rgbd", rgbd={"resume_after": 1}), replay, stamps, path_times)
    # The jump (5 frames in one stamp) does not match: a gap, and the odometry resumes from the camera's new frame, at its last pose.
    assert track.from_camera and track.valid.tolist() == [True, True, False, True] and track.report["resumed"] == 1
    step = relative_pose(path.poses_at(path_times[2:3]), path.poses_at(path_times[3:4]))
    assert float(translation_error(relative_pose(track.poses[1:2], track.poses[3:4]), step)) < 0.005
    scenario = build_scenario(path, config, MapNormalization(), track=track)
    assert scenario.kidnap_tick == 2
    past_the_end = run_times(path, config.model_copy(update={"kidnap_shift": 6 / 30}))[1]  # up to frame 9 of 8: it would wrap to frame 0
    with pytest.raises(LocnerfInputError, match=r"reaches path time 0\.300 s, past its last frame at 0\.233 s.* or --passes 2 or more"):
        sequence_track(OdometrySourceConfig(source="rgbd"), replay, stamps, past_the_end)
    bounced = read_sequence_path(folder, "all", 1, speed=1.0, odom_rate=30.0, frame_rate=30.0, passes=2)
    assert len(list(sequence_rgbd_frames(RecordedReplay(bounced, folder, "all", passes=2), stamps, past_the_end))) == 4
    recorded = OdometryTrack(track.poses, track.valid, "file:recorded.txt")
    with pytest.raises(LocnerfInputError, match=r"odometry file:recorded\.txt with a kidnapping at 0\.05 s: a recorded trajectory follows the recorded camera"):
        build_scenario(path, config, MapNormalization(), track=recorded)
    odometry = write_tum(tmp_path / "odometry.txt", np.arange(5) / 15, torch.eye(4, dtype=torch.float64).repeat(5, 1, 1))
    assert main(_tracking_argv(folder, tmp_path / "run", "--odometry", str(odometry), "--kidnap-at", "0.1")) == 2
    assert re.search(r"--kidnap-at with --odometry .*odometry\.txt: a recorded trajectory .* expected --odometry synthetic, or rgbd", caplog.text)
