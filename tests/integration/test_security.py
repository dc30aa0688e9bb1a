"""Mutual TLS and access control through a router, with real processes and generated certificates.

The router runs ``deploy/zenoh/router-tls.json5`` (the file docker compose gives zenohd) through
``locnerf run router``; the services are its clients with certificates from ``locnerf certs``
(CN = role). What is checked: a client without a certificate gets no session; a certificate
without the command permission cannot re-initialise the filter, the operator's can; only the
worker's certificate may publish update results; the whole loop (sensors, poses, liveliness,
requests and results) works under the policy.
"""

from __future__ import annotations

import time

import pytest

from locnerf.messages import keys
from locnerf.messages.codec import encode
from locnerf.messages.schemas import GlobalLocalizationCommand
from locnerf_cli.certs import make_certificates
from locnerf_services.transport import TransportConfig, open_bus
from locnerf_services.transport.config import TlsConfig
from tests.integration.conftest import ROBOT, wait_for, watch
from tests.integration.routing import client_environment, open_client, start_router, tls_for
from tests.services.helpers import free_port


@pytest.fixture
def certs(tmp_path):
    folder = tmp_path / "certs"
    make_certificates(folder)
    return folder


def test_a_client_without_a_certificate_gets_no_session(hub, certs):
    stack, _, _ = hub
    endpoint = f"tls/127.0.0.1:{free_port()}"
    start_router(stack, "router", endpoint, certs)
    open_client(endpoint, tls_for(certs, "robot")).close()  # the router is up and accepts a certificate
    with pytest.raises(Exception, match="Unable to connect"):
        open_bus(TransportConfig(mode="client", connect=(endpoint,), tls=TlsConfig(root_ca=str(certs / "ca.pem"), mutual=False)))
    with pytest.raises(Exception, match="Unable to connect"):
        open_bus(TransportConfig(mode="client", connect=(endpoint.replace("tls/", "tcp/"),)))


def test_only_the_operator_commands_and_only_workers_publish_results(hub, certs):
    stack, _, _ = hub
    endpoint = f"tls/127.0.0.1:{free_port()}"
    start_router(stack, "router", endpoint, certs)
    robot = open_client(endpoint, tls_for(certs, "robot"))
    clients = [robot]
    try:
        observer = watch(robot)
        common = ("--robot-id", ROBOT, "--device", "cpu")
        stack.start("filter", "run", "filter", *common, environment=client_environment(stack, endpoint, certs, "filter"))
        stack.start("worker", "run", "worker", *common, "--worker-id", "w", environment=client_environment(stack, endpoint, certs, "worker"))
        stack.start(
            "ingest",
            "run",
            "ingest",
            "--robot-id",
            ROBOT,
            "--wait-for-workers",
            "1",
            "--duration",
            "300",
            environment=client_environment(stack, endpoint, certs, "ingest"),
        )
        wait_for(lambda: observer.counter("updates_merged") >= 2 and len(observer.poses) >= 15, 150, "poses and merged updates under the policy", stack)
        assert observer.poses[-1].epoch == 1

        intruders = {role: open_client(endpoint, tls_for(certs, role)) for role in ("ingest", "robot", "worker")}
        operator = open_client(endpoint, tls_for(certs, "operator"))
        clients += [*intruders.values(), operator]
        time.sleep(1.0)  # let the router learn the new sessions' declarations
        command = encode(GlobalLocalizationCommand(stamp=0.0))
        for bus in intruders.values():
            bus.publish(keys.key(ROBOT, keys.GLOBAL_LOCALIZATION), command)
        for bus in (operator, intruders["ingest"], intruders["robot"]):
            bus.publish(keys.key(ROBOT, keys.UPDATE_RESULT), b"\xc1 forged result")
        poses = len(observer.poses)
        wait_for(lambda: len(observer.poses) >= poses + 45, 30, "three more seconds of poses", stack)
        assert {pose.epoch for pose in observer.poses[poses:]} == {1}, "a command from a certificate without the permission re-initialised the filter"
        assert observer.counter("bad_messages") == 0, f"a forbidden publication reached the filter: {observer.status.counters}"

        # Positive controls: the operator's command and a worker's (garbage) result are delivered.
        intruders["worker"].publish(keys.key(ROBOT, keys.UPDATE_RESULT), b"\xc1 garbage from a worker certificate")
        operator.publish(keys.key(ROBOT, keys.GLOBAL_LOCALIZATION), command)
        wait_for(lambda: observer.poses[-1].epoch == 2, 30, "re-initialisation by the operator (epoch 2)", stack)
        wait_for(lambda: observer.counter("bad_undecodable") == 1, 30, "the worker certificate's result to reach the filter", stack)
    finally:
        for bus in clients:
            bus.close()
