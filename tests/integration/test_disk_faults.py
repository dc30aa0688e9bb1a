"""A real filter whose state file cannot be written keeps publishing a pose for every odometry message."""

from __future__ import annotations

from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.supervisor import write_config
from tests.integration.conftest import ROBOT, wait_for

ODOMETRY_PERIOD = 1 / 15


def test_filter_with_an_unwritable_state_file_keeps_its_pose_stream(hub, tmp_path):
    stack, observer, _ = hub
    loop = FilterLoopConfig(state_file=str(tmp_path / "missing_folder" / "filter_state.json"), state_save_rate=2.0)
    config = write_config(tmp_path / "filter.toml", FilterProcessConfig(loop=loop))
    robot = ("--robot-id", ROBOT)
    stack.start("filter", "run", "filter", *robot, "--device", "cpu", "--localizer", "llff", "--config", str(config))
    stack.start("ingest", "run", "ingest", *robot, "--duration", "300")
    wait_for(lambda: len(observer.poses) > 0, 120, "the first pose", stack)
    wait_for(lambda: observer.counter("state_save_failures") >= 3, 30, "three failed saves counted", stack)
    first = len(observer.poses)
    wait_for(lambda: len(observer.poses) >= first + 45, 30, "three more seconds of poses", stack)
    assert stack.processes["filter"].poll() is None
    with observer.lock:
        stamps = [pose.stamp for pose in observer.poses[first:]]
    # Every 15 Hz odometry message gave a pose: consecutive stamps one period apart (5 % tolerance).
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    assert all(abs(gap - ODOMETRY_PERIOD) < 0.05 * ODOMETRY_PERIOD for gap in gaps), f"pose stamps skipped: {max(gaps):.3f} s"
    assert not (tmp_path / "missing_folder").exists()
