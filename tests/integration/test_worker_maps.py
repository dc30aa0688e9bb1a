"""Real processes on loopback Zenoh: a worker started on another map than the filter's is left out.

The filter and worker ``right`` hold the procedural world; worker ``stranger`` holds a small grid
map file. The stranger's liveliness token announces its map's checksum, so the filter never sends it
a request: it is counted and listed in ``filter/status`` while ``right`` computes every update.
"""

from __future__ import annotations

import torch

from locnerf.field.map_file import save_map
from locnerf.messages import keys
from locnerf.messages.codec import decode
from locnerf.messages.schemas import ServiceStatus
from locnerf.sim.world import ProceduralWorld
from tests.field.test_grid_and_map_file import _tiny_map
from tests.integration.conftest import ROBOT, wait_for


def test_a_worker_on_another_map_is_ignored_and_counted_while_the_right_worker_serves(hub, tmp_path):
    stack, observer, bus = hub
    other_map = save_map(_tiny_map(torch.Generator().manual_seed(0)), tmp_path / "other.locnerf")
    refusals: list[bytes] = []
    stranger: list[ServiceStatus] = []
    bus.subscribe(keys.key(ROBOT, keys.UPDATE_REFUSAL), lambda _k, payload: refusals.append(payload))
    bus.subscribe(keys.key(ROBOT, keys.WORKER_STATUS, worker_id="stranger"), lambda _k, payload: stranger.append(decode(payload, ServiceStatus)))
    robot = ("--robot-id", ROBOT, "--device", "cpu")
    stack.start("filter", "run", "filter", *robot, "--localizer", "llff", "--map", "world")
    stack.start("stranger", "run", "worker", *robot, "--worker-id", "stranger", "--map", str(other_map))
    stack.start("right", "run", "worker", *robot, "--worker-id", "right", "--map", "world")
    stack.start("ingest", "run", "ingest", "--robot-id", ROBOT, "--wait-for-workers", "1", "--duration", "300")

    def seen() -> bool:
        status = observer.status
        return status is not None and status.workers_on_another_map == ["stranger"] and status.workers == ["right"]

    wait_for(seen, 120, "the filter to list stranger as on another map and right as its worker", stack)
    wait_for(lambda: observer.counter("updates_merged") >= 3, 120, "three updates merged", stack)
    wait_for(lambda: len(stranger) > 0, 30, "the stranger's status", stack)
    status = observer.status
    assert status.map_checksum == ProceduralWorld.default().checksum and status.counters["workers_on_another_map"] == 1
    with observer.lock:
        assert observer.results and {result.worker_id for result in observer.results} == {"right"}
        assert refusals == []
    assert stranger[-1].counters["requests_answered"] == 0 and stranger[-1].counters["bad_messages"] == 0
