"""``locnerf map build|eval`` never report a score on frames the map was built from as a held-out figure."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import torch

from locnerf.field.map_file import read_map_archive
from locnerf.train import training_views
from locnerf_cli.main import main

FRAMES = 16  # a nerfstudio transforms.json holds out every 8th frame: 0 and 8


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 random 16×12 images from cameras on an arc 2 units from the origin, looking at it, in a [-1, 1]³ box."""
    folder = tmp_path_factory.mktemp("capture")
    rng = np.random.default_rng(0)
    frames = []
    for index, angle in enumerate(np.linspace(-0.6, 0.6, FRAMES)):
        pose = np.eye(4)
        pose[:3, :3] = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
        pose[:3, 3] = 2.0 * pose[:3, 2]
        cv2.imwrite(str(folder / f"frame_{index:02d}.png"), rng.integers(0, 255, (12, 16, 3), dtype=np.uint8))
        frames.append({"file_path": f"frame_{index:02d}.png", "transform_matrix": pose.tolist()})
    camera = {"fl_x": 12.0, "fl_y": 12.0, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12, "aabb": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]}
    (folder / "transforms.json").write_text(json.dumps({**camera, "frames": frames}))
    return folder


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 0
    return capsys.readouterr().out


def _build(capture: Path, out: Path, split: str, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    argv = ["map", "build", str(capture), "--out", str(out), "--split", split, "--steps", "3", "--voxels", str(8**3), "--seed", "0", "--device", "cpu"]
    return json.loads(_run(argv, capsys))


def test_a_map_built_from_every_frame_reports_no_held_out_score(
    capture: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """``--split all`` trains on the test split's frames too: their score is recorded as a train-set figure, and the
    map records its split. (Before: ``heldout_psnr`` over the 2 training frames, and no split.)"""
    with caplog.at_level(logging.WARNING):
        report = _build(capture, tmp_path / "all.locmap", "all", capsys)
    assert report["heldout_views"] == 0 and "heldout_psnr" not in report and "heldout_ssim" not in report
    assert report["train_frames_views"] == 2 and np.isfinite(report["train_frames_psnr"])
    assert "not held out" in caplog.text
    metadata = read_map_archive(tmp_path / "all.locmap")["info"]["metadata"]
    assert (metadata["train_split"], metadata["train_stride"], metadata["train_views"]) == ("all", 1, FRAMES)


def test_map_eval_scores_training_frames_apart(capture: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A map built from the training split: the build's held-out figure is over the 2 test frames; ``map eval --split
    all`` scores those 2 as held out and the other 14 apart, labelled as train-set figures."""
    out = tmp_path / "train.locmap"
    report = _build(capture, out, "train", capsys)
    assert report["heldout_views"] == 2 and np.isfinite(report["heldout_psnr"]) and "train_frames_views" not in report
    assert report["train_split"] == "train" and report["train_views"] == FRAMES - 2
    scores = json.loads(_run(["map", "eval", str(out), str(capture), "--split", "all", "--json", "--device", "cpu"], capsys))
    assert scores["views"] == 2 and scores["psnr"] == pytest.approx(report["heldout_psnr"], abs=1e-3)
    assert scores["training_frames"]["views"] == FRAMES - 2
    trained_only = json.loads(_run(["map", "eval", str(out), str(capture), "--split", "train", "--json", "--device", "cpu"], capsys))
    assert (trained_only["views"], trained_only["psnr"], trained_only["training_frames"]["views"]) == (0, None, FRAMES - 2)
    text = _run(["map", "eval", str(out), str(capture), "--split", "train", "--device", "cpu"], capsys)
    assert text.startswith("train-set PSNR (not held out)") and "held-out" not in text


def test_training_views_are_the_reference_poses_themselves() -> None:
    reference = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    reference[:, 0, 3] = torch.tensor([0.0, 1.0, 2.0])
    moved = reference[1].clone()
    moved[2, 3] += 1e-4  # a different frame a tenth of a millimetre away
    views = torch.stack((reference[2], moved, reference[0]))
    assert training_views(views, reference).tolist() == [True, False, True]
    assert training_views(views, reference[:0]).tolist() == [False, False, False]
