"""Which workers the filter uses and what it does with their refusals (in-memory, no transport).

A worker's token announces its map's checksum: one on another map is left out, counted, logged
once and listed in the status. A request a worker does not compute is answered with a refusal that
the filter acts on at once: the shard is re-sent to another worker (``failed``, ``wrong_map``) at most
``max_shard_attempts`` times, or the update is given up (``bad_request``); a worker whose computation
fails keeps serving.
"""

from __future__ import annotations

import logging
import threading

import pytest
import torch

from locnerf.messages import keys
from locnerf.messages.codec import decode, encode
from locnerf.messages.schemas import RefusalReason, ServiceStatus, UpdateRefusal, UpdateRequest, UpdateResult
from locnerf.sim.world import ProceduralWorld, WorldConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.nerf_worker.__main__ import serve
from locnerf_services.nerf_worker.service import NerfWorker
from locnerf_services.transport.memory import MemoryBus
from tests.services.filter_harness import ROBOT, Harness, image_payload, odometry_payload
from tests.services.helpers import wait_until

OTHER_MAP = "f" * 64


@pytest.fixture(scope="module")
def world() -> ProceduralWorld:
    return ProceduralWorld.default()


class FailingMap:
    """The world whose renders raise CUDA's out-of-memory error for the first ``failures`` calls (all of them by default)."""

    def __init__(self, world: ProceduralWorld, failures: int = 10**9) -> None:
        self.world, self.failures = world, failures
        self.device, self.normalization, self.checksum = world.device, world.normalization, world.checksum

    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        if self.failures > 0:
            self.failures -= 1
            raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB (injected)")
        return self.world.render_rays(origins, directions)


def _start_update(harness: Harness, world: ProceduralWorld, generator: torch.Generator) -> None:
    """Odometry and an image at 0 s, then a tick: the update's shards land in ``harness.requests``."""
    harness.collect(harness.loop.handle_odometry(odometry_payload(0.0, torch.eye(4, dtype=torch.float64))))
    harness.collect(harness.loop.handle_image(image_payload(world, 0.0, world.sample_camera_pose(generator))))
    harness.tick()


def _refuse(harness: Harness, worker: NerfWorker, request: UpdateRequest) -> UpdateRefusal:
    """``worker``'s answer to ``request``, which must be a refusal, fed to the filter."""
    answer = worker.answer(request)
    assert isinstance(answer, UpdateRefusal), answer
    harness.collect(harness.loop.handle_refusal(encode(answer)))
    return answer


def test_a_worker_on_another_map_is_left_out_counted_reported_and_logged_once(world, generator, caplog):
    harness = Harness(world)
    with caplog.at_level(logging.WARNING, logger="locnerf_services.filter_loop.dispatcher"):
        harness.add_worker("stranger", map_checksum=OTHER_MAP)
        _start_update(harness, world, generator)
        assert harness.requests == [] and harness.loop.dispatcher.pending == {}, "an update went to a worker on another map"
        harness.add_worker("stranger", alive=False, map_checksum=OTHER_MAP)
        harness.add_worker("stranger", map_checksum=OTHER_MAP)  # back again, on the same other map
        harness.add_worker("w1")
        harness.tick()
    ((worker, request),) = harness.requests
    assert worker == "w1" and request.map_checksum == world.checksum
    status = harness.loop.status()
    assert status.workers == ["w1"] and status.workers_on_another_map == ["stranger"] and status.map_checksum == world.checksum
    assert status.counters["workers_on_another_map"] == 2
    assert [r.getMessage() for r in caplog.records].count(f"worker stranger holds map {OTHER_MAP}, not the filter's map {world.checksum}: it is left out") == 1
    harness.add_worker("stranger", alive=False, map_checksum=OTHER_MAP)
    assert harness.loop.status().workers_on_another_map == []


def test_a_worker_refuses_a_request_for_another_map_and_the_filter_resends_the_shard_at_once(world, generator):
    """A worker whose token claimed the filter's map but that holds another refuses (wrong_map): its shard goes to
    the other worker without waiting for the timeout, and the refusing worker is left out from then on."""
    harness = Harness(world)
    harness.add_worker("w1")
    harness.add_worker("w2")
    _start_update(harness, world, generator)
    shards = dict(harness.requests)
    harness.requests.clear()
    refusal = _refuse(harness, NerfWorker(ProceduralWorld(WorldConfig(seed=8)), "w1"), shards["w1"])
    assert refusal.reason is RefusalReason.WRONG_MAP and refusal.map_checksum != world.checksum
    ((worker, resent),) = harness.requests
    assert worker == "w2" and resent == shards["w1"]
    harness.answer(shards["w2"])
    harness.answer(resent)
    counters = harness.loop.counters()
    assert counters["updates_merged"] == 1 and counters["shards_refused_wrong_map"] == 1 and counters["shards_retried"] == 1
    assert harness.loop.status().workers == ["w2"] and harness.loop.status().workers_on_another_map == ["w1"]


def test_a_bad_request_gives_the_update_up_at_once(world, generator):
    harness = Harness(world)
    harness.add_worker("w1")
    _start_update(harness, world, generator)
    ((_worker, request),) = harness.requests
    harness.requests.clear()
    outside = request.model_copy(update={"pixels": [[500.0, 1.0]] * len(request.pixels)})  # a request the worker cannot evaluate
    assert _refuse(harness, NerfWorker(world, "w1"), outside).reason is RefusalReason.BAD_REQUEST
    assert harness.requests == [] and harness.loop.dispatcher.pending == {}
    counters = harness.loop.counters()
    assert counters["shards_refused_bad_request"] == 1 and counters["updates_given_up"] == 1 and "updates_timed_out" not in counters
    harness.answer(request)  # the worker's result after all: late, not bad
    assert harness.loop.counters()["late_results"] == 1 and harness.loop.counters()["bad_messages"] == 0


def test_a_failing_shard_goes_to_each_worker_once_at_most_max_shard_attempts_times_then_the_update_is_given_up(world, generator):
    """Every worker fails (out of GPU memory): each refusal re-sends the shard to a worker it has not been to,
    three sends in all, then the update is given up; nothing waits for the timeout, and the next update can start."""
    harness = Harness(world, FilterLoopConfig(max_shard_attempts=3))
    names = ["w1", "w2", "w3", "w4"]
    for name in names:
        harness.add_worker(name)
    workers = {name: NerfWorker(FailingMap(world), name) for name in names}
    _start_update(harness, world, generator)
    sent: dict[int, list[str]] = {}
    refusals = 0
    while harness.requests:
        worker, request = harness.requests.pop(0)
        sent.setdefault(request.shard, []).append(worker)
        assert _refuse(harness, workers[worker], request).reason is RefusalReason.FAILED
        refusals += 1
        assert refusals < 50, "a failing shard is passed on from worker to worker without end"
    counters = harness.loop.counters()
    assert counters["updates_given_up"] == 1 and harness.loop.dispatcher.pending == {}
    assert max(len(tried) for tried in sent.values()) == 3 and all(len(set(tried)) == len(tried) for tried in sent.values()), sent
    assert counters["shards_refused_failed"] + counters.get("late_results", 0) == refusals


def test_a_worker_whose_computation_fails_answers_failed_and_keeps_serving(world, generator):
    """Over the in-memory bus: the token announces the map's checksum; a request whose render raises is answered
    with a ``failed`` refusal, the next one with its result, and the worker's status counts the failure."""
    harness = Harness(world)
    harness.add_worker("w")
    _start_update(harness, world, generator)
    ((_worker, request),) = harness.requests
    harness.requests.clear()
    bus, stop = MemoryBus(), threading.Event()
    tokens: list[str] = []
    bus.watch_liveliness(keys.workers_alive_pattern(ROBOT), lambda key, alive: tokens.append(key) if alive else None)
    answers: list[UpdateResult | UpdateRefusal] = []
    bus.subscribe(keys.key(ROBOT, keys.UPDATE_RESULT), lambda _k, payload: answers.append(decode(payload, UpdateResult)))
    bus.subscribe(keys.key(ROBOT, keys.UPDATE_REFUSAL), lambda _k, payload: answers.append(decode(payload, UpdateRefusal)))
    statuses: list[ServiceStatus] = []
    bus.subscribe(keys.key(ROBOT, keys.WORKER_STATUS, worker_id="w"), lambda _k, payload: statuses.append(decode(payload, ServiceStatus)))
    thread = threading.Thread(target=serve, args=(NerfWorker(FailingMap(world, failures=1), "w"), bus, ROBOT, "cpu", stop))
    thread.start()
    try:
        wait_until(lambda: tokens == [keys.key(ROBOT, keys.WORKER_ALIVE, worker_id="w", device="cpu", map_checksum=world.checksum)], 10, "the token")
        for _ in range(2):
            bus.publish(keys.key(ROBOT, keys.UPDATE_REQUEST, worker_id="w"), encode(request))
        wait_until(lambda: len(answers) == 2, 30, "two answers")
        wait_until(lambda: any(s.counters.get("requests_failed") == 1 for s in statuses), 10, "a status counting the failure")
    finally:
        stop.set()
        thread.join(timeout=10)
    failed, result = answers
    assert isinstance(failed, UpdateRefusal) and failed.reason is RefusalReason.FAILED and "OutOfMemoryError: CUDA out of memory" in failed.detail
    assert isinstance(result, UpdateResult) and result.ids == request.ids
    harness.collect(harness.loop.handle_refusal(encode(failed)))  # one worker: the shard goes back to it
    ((worker, resent),) = harness.requests
    assert worker == "w" and resent == request
    harness.collect(harness.loop.handle_result(encode(result)))
    assert harness.loop.counters()["updates_merged"] == 1
