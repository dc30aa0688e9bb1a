"""Process and network faults with real processes on loopback Zenoh: a worker killed while an
update is in flight, and the router restarted under services that are its clients ($LOCNERF_FAULT_ROUTER_RESTARTS times,
1 in the suite).

Only liveness is asserted (the pose stream goes on, updates resume); the measured figures
(poses lost, gaps) are appended to $LOCNERF_FAULT_REPORT when set (tests/integration/fault_report.py)
and written down in docs/RELIABILITY.md.
"""

from __future__ import annotations

import os
import signal
import time

from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.supervisor import write_config
from tests.integration.conftest import ROBOT, Observer, Stack, wait_for, watch
from tests.integration.fault_report import poses_lost, report
from tests.integration.routing import client_environment, open_client, start_router
from tests.services.helpers import free_port

COMMON = ("--robot-id", ROBOT, "--device", "cpu")


def filter_config(tmp_path, update_timeout: float = 2.0):
    return write_config(tmp_path / "filter.toml", FilterProcessConfig(loop=FilterLoopConfig(update_timeout=update_timeout)))


def start_services(stack: Stack, tmp_path, environment: dict[str, str] | None = None) -> None:
    stack.start("filter", "run", "filter", *COMMON, "--config", str(filter_config(tmp_path)), environment=environment)
    stack.start("wa", "run", "worker", *COMMON, "--worker-id", "wa", environment=environment)
    stack.start("ingest", "run", "ingest", "--robot-id", ROBOT, "--wait-for-workers", "1", "--duration", "300", environment=environment)


def merged(observer: Observer) -> int:
    return observer.counter("updates_merged")


def test_a_worker_killed_mid_update_is_abandoned_and_its_restart_is_used_again(hub, tmp_path):
    stack, observer, _ = hub
    start_services(stack, tmp_path)
    wait_for(lambda: merged(observer) >= 3, 150, "merged updates", stack)

    # Freeze the only worker so that requests stay in flight, then SIGKILL it.
    stack.processes["wa"].send_signal(signal.SIGSTOP)
    wait_for(
        lambda: observer.status.in_flight >= 1 and observer.status.counters.get("updates_started", 0) > merged(observer) + 1,
        30,
        "an update in flight to the frozen worker",
        stack,
    )
    first_stamp = observer.poses[-1].stamp
    in_flight = observer.status.in_flight
    stack.kill("wa")
    wait_for(lambda: observer.workers() == [], 30, "the filter to see the worker gone", stack)
    wait_for(lambda: observer.counter("updates_timed_out") >= 1, 30, "the in-flight update abandoned", stack)
    poses = len(observer.poses)
    wait_for(lambda: len(observer.poses) >= poses + 30, 30, "poses without any worker", stack)

    before = merged(observer)
    stack.start("wa2", "run", "worker", *COMMON, "--worker-id", "wa2")
    wait_for(lambda: observer.workers() == ["wa2"], 60, "the restarted worker to join", stack)
    wait_for(lambda: merged(observer) >= before + 3, 60, "updates merged by the restarted worker", stack)
    assert {result.worker_id for result in observer.results[-3:]} == {"wa2"}
    last_stamp = observer.poses[-1].stamp
    report(
        "worker_killed_mid_update",
        kills=1,
        in_flight_at_kill=in_flight,
        updates_timed_out=observer.counter("updates_timed_out"),
        poses_lost=poses_lost(observer.poses, first_stamp, last_stamp),
        sensor_seconds=round(last_stamp - first_stamp, 2),
    )


def test_services_reconnect_after_the_router_restarts(hub, tmp_path):
    stack, _, _ = hub
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    start_router(stack, "router", endpoint)
    robot = open_client(endpoint)
    try:
        observer = watch(robot)
        start_services(stack, tmp_path, client_environment(stack, endpoint))
        wait_for(lambda: merged(observer) >= 3, 150, "merged updates through the router", stack)

        gaps, lost, accepting = [], [], []
        restarts = int(os.environ.get("LOCNERF_FAULT_ROUTER_RESTARTS", "1"))
        for restart in range(restarts):
            wait_for(lambda: len(observer.poses) >= 15, 30, "poses", stack)
            last_before, stamp_before = observer.pose_arrivals[-1], observer.poses[-1].stamp
            stack.kill("router")
            killed = time.monotonic()
            start_router(stack, "router", endpoint)
            count = len(observer.poses)
            open_client(endpoint).close()  # a probe: the new router accepts sessions (retried every 0.3 s)
            accepting.append(round(time.monotonic() - killed, 2))
            wait_for(lambda: len(observer.poses) >= count + 30, 90, f"poses after router restart {restart + 1}", stack)
            with observer.lock:
                resumed = observer.pose_arrivals[count]
                stamp_after = observer.poses[-1].stamp
            gaps.append(round(resumed - last_before, 2))
            lost.append(poses_lost(observer.poses, stamp_before, stamp_after))
            before = merged(observer)
            wait_for(lambda: merged(observer) >= before + 3 and observer.workers() == ["wa"], 60, "updates after the restart", stack)
            assert all(stack.processes[name].poll() is None for name in ("filter", "wa", "ingest"))
            assert killed - last_before < 1.0  # the poses were flowing when the router died
        report("router_restart", restarts=restarts, router_accepting_after_s=accepting, pose_gap_s=gaps, poses_lost=lost)
    finally:
        robot.close()
