"""``locnerf up --view --save``: the services on the world with the view beside them, its recording read back.

The test's own session subscribes to the filter's poses while the stack runs; the recording is read
with rerun's reader (``rerun.chunk.RrdReader``), not with the view's code. Every estimate the view
recorded after the test's first received pose must be one the filter published: same stamp (whole
nanoseconds) and, within float32, the same position and rotation. The map and particle entities
must hold points. Counted, not timed: the run stops after a few merged updates.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading

import numpy as np
import pyarrow as pa
import pytest

from locnerf.messages import keys
from locnerf.messages.codec import decode
from locnerf.messages.schemas import PoseEstimate
from locnerf_services.supervisor import free_port
from locnerf_services.transport import TransportConfig, open_bus
from tests.integration.conftest import REPO
from tests.services.helpers import wait_until

rerun_chunk = pytest.importorskip("rerun.chunk", reason="the view extra: pip install 'locnerf[view]'")

ROBOT = "viewtest"
UPDATES = 4


def recorded(path) -> dict[str, list[pa.RecordBatch]]:
    """Record batches of the recording by entity path."""
    batches: dict[str, list[pa.RecordBatch]] = {}
    for chunk in rerun_chunk.RrdReader(path).stream().to_chunks():
        batches.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return batches


def recorded_poses(batches: list[pa.RecordBatch]) -> dict[int, np.ndarray]:
    """stamp_ns -> recorded (4, 4) pose, from the Transform3D rows of an entity."""
    poses = {}
    for batch in batches:
        stamps = batch.column("stamp").cast(pa.int64()).to_pylist()
        translations = batch.column("Transform3D:translation").to_pylist()
        rotations = batch.column("Transform3D:mat3x3").to_pylist()
        for stamp, translation, rotation in zip(stamps, translations, rotations, strict=True):
            pose = np.eye(4)
            pose[:3, 3] = translation[0]
            pose[:3, :3] = np.asarray(rotation[0]).reshape(3, 3, order="F")  # rerun stores 3×3 matrices column-major
            poses[stamp] = pose
    return poses


def listening(port: int) -> bool:
    """Whether something accepts TCP connections on 127.0.0.1:``port``."""
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def test_up_view_records_what_the_filter_published(tmp_path):
    port = free_port()
    rrd = tmp_path / "run.rrd"
    command = [sys.executable, "-m", "locnerf_cli.main", "up", "--until-updates", str(UPDATES), "--json", "--port", str(port), "--seed", "1"]
    command += ["--robot-id", ROBOT, "--logs", str(tmp_path / "logs"), "--view", "--save", str(rrd)]
    stack = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    published: dict[int, PoseEstimate] = {}
    lock = threading.Lock()

    def on_pose(_key: str, payload: bytes) -> None:
        estimate = decode(payload, PoseEstimate)
        with lock:
            published[estimate.stamp_ns] = estimate

    wait_until(lambda: listening(port), 60, f"locnerf up listening on port {port}")
    bus = open_bus(TransportConfig(connect=(f"tcp/127.0.0.1:{port}",)))
    subscription = bus.subscribe(keys.key(ROBOT, keys.POSE), on_pose)
    try:
        out, err = stack.communicate(timeout=240)
    finally:
        stack.kill()
        subscription.close()
        bus.close()
    logs = "".join(p.read_text()[-1500:] for p in (tmp_path / "logs").glob("*.log"))
    assert stack.returncode == 0, err + logs
    assert rrd.is_file(), logs

    batches = recorded(rrd)
    poses = recorded_poses(batches["/world/estimate"])
    assert len(published) > 0 and len(poses) > 0, (len(published), len(poses), logs)
    first_seen = min(published)
    checked = 0
    for stamp, pose in poses.items():
        if stamp < first_seen:
            continue  # before the test's session received anything
        assert stamp in published, f"recorded stamp {stamp} ns was never published"
        truth = np.asarray(published[stamp].T_world_cam)
        np.testing.assert_allclose(pose[:3, 3], truth[:3, 3], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(pose[:3, :3], truth[:3, :3], rtol=1e-6, atol=1e-6)
        checked += 1
    assert checked >= 5, (checked, len(poses), len(published))

    map_points = batches["/world/map"][0]
    assert len(map_points.column("Points3D:positions").to_pylist()[0]) > 1000
    assert len(map_points.column("Points3D:colors").to_pylist()[0]) == len(map_points.column("Points3D:positions").to_pylist()[0])
    clouds = [row for batch in batches["/world/particles"] for row in batch.column("Points3D:positions").to_pylist() if row]
    assert clouds and all(len(cloud) > 0 for cloud in clouds)
    assert "/world/truth" in batches and "/error/translation_m" in batches and "/camera/image" in batches
