"""``python -m services.nerf_worker``: serve update requests for one map until stopped."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from locnerf.devices import resolve_device
from locnerf.maps.source import open_map
from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode, encode
from locnerf.messages.schemas import RefusalReason, UpdateRefusal, UpdateRequest
from locnerf_services.nerf_worker.service import NerfWorker
from locnerf_services.runtime import BadMessages, StatusPublisher, default_instance_id, limit_torch_threads, load_service_config, service_main, stop_on_signals
from locnerf_services.transport import Bus, Inbox, TransportConfig, open_bus

logger = logging.getLogger(__name__)


class WorkerConfig(BaseModel):
    """A NeRF worker process."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    robot_id: str = Field("robot", description="Robot whose keys (locnerf/<robot_id>/...) the worker serves.")
    map: str = Field(
        "world",
        description="Map to load: 'world' (the procedural world) or a map file path; the filter's map, else the filter leaves this worker out.",
    )
    device: str = Field("auto", description="auto, cpu, cuda or cuda:N.")
    worker_id: str = Field("", description="Name of this worker (empty: <hostname>-<pid>).")
    torch_threads: int = Field(1, ge=1, description="Intra-op threads of torch in this process (1 suits several services per machine).")
    nice: int = Field(
        10,
        ge=0,
        le=19,
        description="Niceness added to this process: renders are throughput work and should yield the CPU to the filter's "
        "pose stream when both share a machine (0: same priority).",
    )
    transport: TransportConfig = Field(default_factory=TransportConfig, description="Zenoh session settings.")


def serve(worker: NerfWorker, bus: Bus, robot_id: str, device_name: str, stop: threading.Event) -> BadMessages:
    """Answer requests addressed to this worker until ``stop`` is set; returns the bad-message counts.

    Every decoded request is answered with its result or an UpdateRefusal (a request for another map and a
    bad request are also counted as bad messages, ``bad_wrong_map`` and ``bad_bad_request``; a failed one as
    ``requests_failed``). Publishes a ServiceStatus (requests answered, bad messages by kind, failures, inbox
    drops) every second. The liveliness token announces the worker's device and map checksum."""
    bad = BadMessages("nerf_worker")
    inbox: Inbox[bytes] = Inbox(capacity=8)
    status = StatusPublisher(bus.publish, keys.key(robot_id, keys.WORKER_STATUS, worker_id=worker.worker_id), "nerf_worker", worker.worker_id, bad)
    answered = failed = 0
    subscription = bus.subscribe(keys.key(robot_id, keys.UPDATE_REQUEST, worker_id=worker.worker_id), lambda _k, payload: inbox.put(payload))
    token = bus.declare_token(keys.key(robot_id, keys.WORKER_ALIVE, worker_id=worker.worker_id, device=device_name, map_checksum=worker.map_checksum))
    result_key, refusal_key = keys.key(robot_id, keys.UPDATE_RESULT), keys.key(robot_id, keys.UPDATE_REFUSAL)
    logger.info("worker %s serving robot %s with map %s", worker.worker_id, robot_id, worker.map_checksum)
    try:
        while not stop.is_set():
            status.publish_if_due({"requests_answered": answered, "requests_failed": failed, "inbox_dropped": inbox.dropped})
            payload = inbox.get(timeout=0.1)
            if payload is None:
                continue
            try:
                request = decode(payload, UpdateRequest)
            except DecodeError as error:
                bad.record(error.kind, error.reason)
                continue
            answer = worker.answer(request)
            if isinstance(answer, UpdateRefusal):
                if answer.reason is RefusalReason.FAILED:
                    failed += 1
                else:
                    bad.record(answer.reason.value, answer.detail)
                bus.publish(refusal_key, encode(answer))
                continue
            bus.publish(result_key, encode(answer))
            answered += 1
    finally:
        token.close()
        subscription.close()
    return bad


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Command-line options of the worker."""
    parser.add_argument("--config", type=Path, help="TOML file with WorkerConfig fields")
    parser.add_argument("--robot-id", dest="robot_id", help="robot id (overrides the file)")
    parser.add_argument("--map", help="'world' or a map file (overrides the file)")
    parser.add_argument("--device", help="auto, cpu, cuda or cuda:N (overrides the file)")
    parser.add_argument("--worker-id", dest="worker_id", help="name of this worker (overrides the file)")


def run(args: argparse.Namespace) -> int:
    """Load the map, open the bus and serve until SIGINT/SIGTERM."""
    config = load_service_config(WorkerConfig, args.config, {k: getattr(args, k) for k in ("robot_id", "map", "device", "worker_id")})
    limit_torch_threads(config.torch_threads)
    if config.nice:
        os.nice(config.nice)
    device = resolve_device(config.device)
    worker = NerfWorker(open_map(config.map, device), config.worker_id or default_instance_id())
    stop = stop_on_signals()
    bus = open_bus(config.transport.with_environment())
    try:
        serve(worker, bus, config.robot_id, device.type, stop)
    finally:
        bus.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    return service_main("python -m services.nerf_worker", __doc__, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
