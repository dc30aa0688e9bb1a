"""docs/TUTORIAL.md runs: its ``bash`` blocks, in order, as one script, on a tiny sample of the lego scene.

The first block's ``NAME=value`` lines are the tutorial's settings; the test gives each of them a
small value (a sample of lego frames at 64 × 64 written from ../shared/data, a map of a few steps on
a coarse grid, live runs of 2 s after the first pose) and keeps the block's other lines. A failing command fails
the test with the block it belongs to and the end of its output. Then every file the page promises
is checked, with readers other than the commands that wrote it: the map file's header, the PNG, the
tracking JSON and TUM trajectories, the recording through rerun's own reader.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from locnerf.field.map_file import read_map_info

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "TUTORIAL.md"
LEGO = ROOT.parent / "shared" / "data" / "nerf_synthetic" / "lego"
ORBIT = ROOT.parent / "shared" / "data" / "nerf_synthetic" / "lego_test_orbit"
BASH_BLOCK = re.compile(r"^```bash\n(.*?)^```", re.MULTILINE | re.DOTALL)
SETTING = re.compile(r"^([A-Z_]+)=\S+(\s+#.*)?$")
SAMPLE_SIZE = 64
TRAIN_FRAMES, TEST_FRAMES = 12, 40


def bash_blocks(text: str) -> list[str]:
    """The ``bash`` code blocks of a Markdown page, in order."""
    return BASH_BLOCK.findall(text)


def settings_of(block: str) -> tuple[list[str], list[str]]:
    """(names of the ``NAME=value`` lines, the block's other lines)."""
    names, rest = [], []
    for line in block.splitlines():
        match = SETTING.match(line)
        if match:
            names.append(match.group(1))
        else:
            rest.append(line)
    return names, rest


def write_sample(folder: Path) -> Path:
    """A NeRF-synthetic folder at 64 × 64 (RGBA): TRAIN_FRAMES lego training views spread over the split, and the
    first TEST_FRAMES views of the lego test orbit, consecutive as in the full data set (the tracked trajectory)."""
    for split, source, spread in (("train", LEGO, True), ("test", ORBIT, False)):
        meta = json.loads((source / f"transforms_{split}.json").read_text())
        count = TRAIN_FRAMES if split == "train" else TEST_FRAMES
        frames = meta["frames"][:: len(meta["frames"]) // count][:count] if spread else meta["frames"][:count]
        (folder / split).mkdir(parents=True, exist_ok=True)
        for frame in frames:
            image = cv2.imread(str(source / f"{frame['file_path']}.png"), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(folder / f"{frame['file_path']}.png"), cv2.resize(image, (SAMPLE_SIZE, SAMPLE_SIZE), interpolation=cv2.INTER_AREA))
        (folder / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": meta["camera_angle_x"], "frames": frames}))
    return folder


def test_the_settings_are_the_ones_this_test_gives_values():
    names, _ = settings_of(bash_blocks(TUTORIAL.read_text())[0])
    assert sorted(names) == sorted(["DATA", "OUT", "STEPS", "VOXELS", "DOWNSCALE", "LIVE_SECONDS"])


def tum_poses(path: Path) -> np.ndarray:
    """(N, 8) rows of a TUM trajectory: stamp, x, y, z, qx, qy, qz, qw."""
    rows = np.loadtxt(path, comments="#", ndmin=2)
    assert rows.shape[1] == 8 and len(rows) > 0, path
    return rows


@pytest.mark.slow
@pytest.mark.skipif(not (LEGO.is_dir() and ORBIT.is_dir()), reason="needs ../shared/data/nerf_synthetic/lego and lego_test_orbit")
def test_every_command_of_the_tutorial_runs_on_a_tiny_sample(tmp_path):
    text = TUTORIAL.read_text()
    blocks = bash_blocks(text)
    out = tmp_path / "out"
    values = {"DATA": str(write_sample(tmp_path / "lego")), "OUT": str(out), "STEPS": "20", "VOXELS": "32768", "DOWNSCALE": "1", "LIVE_SECONDS": "2"}
    _, first_rest = settings_of(blocks[0])
    script = ["set -euo pipefail", *(f"{name}={shlex.quote(value)}" for name, value in values.items())]
    for index, block in enumerate([("\n".join(first_rest)), *blocks[1:]]):
        script += [f"echo '### tutorial block {index + 1}' >&2", block]
    environment = os.environ | {"PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    environment = {k: v for k, v in environment.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(["bash", "-c", "\n".join(script)], capture_output=True, text=True, cwd=ROOT, env=environment, timeout=400)
    failed_in = re.findall(r"### tutorial block (\d+)", result.stderr)
    assert result.returncode == 0, f"block {failed_in[-1] if failed_in else '?'} failed:\n{result.stderr[-3000:]}"

    promised = ["lego.locmap", "view0.png", "tracking/tracking.json", "tracking/reference.txt", "tracking/odometry.txt", "run.rrd"]
    for name in [*promised, "tracking/estimate.txt"]:
        assert f"$OUT/{name}" in text, f"the page no longer names $OUT/{name}"
    for name in promised:
        assert (out / name).is_file(), f"$OUT/{name} was not written"

    _, info = read_map_info(out / "lego.locmap")
    assert info.intrinsics.width == SAMPLE_SIZE and info.metadata["steps"] == 20
    view = cv2.imread(str(out / "view0.png"))
    assert view.shape == (SAMPLE_SIZE, SAMPLE_SIZE, 3)

    # estimate.txt exists exactly when the filter converged (a map of 20 steps seldom lets it).
    report = json.loads((out / "tracking" / "tracking.json").read_text())
    assert (out / "tracking" / "estimate.txt").is_file() == (report["converged_after_s"] is not None)
    reference, odometry = tum_poses(out / "tracking" / "reference.txt"), tum_poses(out / "tracking" / "odometry.txt")
    assert np.isfinite(reference).all() and np.isfinite(odometry).all() and report["poses"] > 0

    rerun_chunk = pytest.importorskip("rerun.chunk")
    rows = {}
    for chunk in rerun_chunk.RrdReader(out / "run.rrd").stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    # (A map of 20 steps has no opaque surface yet, so no /world/map: tests/maps/test_cloud.py covers it.)
    assert rows.get("/world/estimate", 0) > 0 and rows.get("/world/particles", 0) > 0 and rows.get("/camera/image", 0) > 0, rows
