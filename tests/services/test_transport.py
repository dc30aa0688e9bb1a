"""Transport: key matching, inboxes, the in-memory bus, env configuration, and Zenoh on loopback."""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

import pytest
import zenoh

from locnerf_services.transport import Inbox, LatestSlot, TransportConfig, open_bus
from locnerf_services.transport.memory import MemoryBus, key_matches
from locnerf_services.transport.router import Router, router_config
from tests.ros2.rmw_client import RmwServiceClient
from tests.services.helpers import free_port, wait_until

ROUTER_FILE = Path(__file__).resolve().parents[2] / "deploy/zenoh/router.json5"


@pytest.mark.parametrize(
    ("pattern", "key", "expected"),
    [
        ("a/b", "a/b", True),
        ("a/*", "a/b", True),
        ("a/*", "a/b/c", False),
        ("a/**", "a/b/c", True),
        ("a/**/c", "a/c", True),
        ("a/*/c", "a/b/d", False),
    ],
)
def test_key_matching(pattern, key, expected):
    assert key_matches(pattern, key) is expected


def test_inbox_drops_the_oldest_when_full_and_never_blocks():
    inbox: Inbox[int] = Inbox(capacity=2)
    for item in range(3):
        inbox.put(item)
    assert (inbox.get(0.0), inbox.get(0.0), inbox.get(0.0), inbox.dropped) == (1, 2, None, 1)


def test_inbox_wakes_a_waiting_reader():
    inbox: Inbox[str] = Inbox()
    threading.Timer(0.05, inbox.put, args=("hello",)).start()
    assert inbox.get(timeout=5.0) == "hello"


def test_latest_slot_keeps_only_the_newest():
    slot: LatestSlot[int] = LatestSlot()
    slot.put(1)
    slot.put(2)
    assert (slot.take(), slot.take(), slot.replaced) == (2, None, 1)


def test_memory_bus_delivers_and_tracks_liveliness():
    bus = MemoryBus()
    got, alive = [], []
    bus.subscribe("x/**", lambda key, payload: got.append((key, payload)))
    token = bus.declare_token("live/w1")
    bus.watch_liveliness("live/*", lambda key, up: alive.append((key, up)))
    bus.publish("x/y/z", b"1")
    bus.publish("other", b"2")
    token.close()
    assert got == [("x/y/z", b"1")]
    assert alive == [("live/w1", True), ("live/w1", False)]


def test_transport_config_reads_the_environment():
    config = TransportConfig().with_environment({"LOCNERF_ZENOH_MODE": "client", "LOCNERF_ZENOH_CONNECT": "tcp/zenohd:7447, tcp/b:1"})
    assert config.mode == "client" and config.connect == ("tcp/zenohd:7447", "tcp/b:1")
    with pytest.raises(ValueError, match="endpoint"):
        TransportConfig(connect=("localhost",))


def test_zenoh_bus_on_loopback_publishes_and_reports_liveliness():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_bus(TransportConfig(listen=(endpoint,)))
    a = open_bus(TransportConfig(connect=(endpoint,)))
    b = open_bus(TransportConfig(connect=(endpoint,)))
    try:
        got: Inbox[bytes] = Inbox()
        alive: list[tuple[str, bool]] = []
        b.subscribe("t/**", lambda _key, payload: got.put(payload))
        b.watch_liveliness("live/**", lambda key, up: alive.append((key, up)))
        token = a.declare_token("live/w")
        wait_until(lambda: ("live/w", True) in alive, 20.0, "the token to be seen")
        deadline = time.monotonic() + 20.0
        received = None
        while received is None and time.monotonic() < deadline:
            a.publish("t/1", b"payload")
            received = got.get(timeout=0.2)
        assert received == b"payload"
        token.close()
        wait_until(lambda: ("live/w", False) in alive, 20.0, "the token to vanish")
    finally:
        for bus in (a, b, hub):
            bus.close()


def test_memory_bus_carries_attachments_and_answers_queries():
    bus = MemoryBus()
    got = []
    bus.subscribe_attached("x/*", lambda key, payload, attachment: got.append((key, payload, attachment)))
    bus.publish("x/a", b"1", attachment=b"meta")
    bus.publish("x/b", b"2")
    bus.declare_queryable("srv/*/*", lambda key, payload, attachment: [(key, payload + b"!", attachment)])
    assert got == [("x/a", b"1", b"meta"), ("x/b", b"2", None)]
    assert bus.query("srv/t/h", b"q", attachment=b"a") == [("srv/t/h", b"q!", b"a")]
    assert bus.query("other", b"q") == []
    assert len(bus.session_id) == 32


def test_zenoh_bus_on_loopback_carries_attachments_and_answers_queries():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_bus(TransportConfig(listen=(endpoint,)))
    a = open_bus(TransportConfig(connect=(endpoint,)))
    ros_client = RmwServiceClient(TransportConfig(connect=(endpoint,)))
    try:
        got: Inbox[tuple[bytes, bytes | None]] = Inbox()
        hub.subscribe_attached("t/**", lambda _key, payload, attachment: got.put((payload, attachment)))
        a.declare_queryable("srv/*/*", lambda key, payload, attachment: [(key, payload + b"!", attachment)], complete=True)
        received = None
        deadline = time.monotonic() + 20.0
        while received is None and time.monotonic() < deadline:
            a.publish("t/1", b"payload", attachment=b"\x01\x02")
            received = got.get(timeout=0.2)
        assert received == (b"payload", b"\x01\x02")
        wait_until(lambda: hub.query("srv/t/h", b"q", attachment=b"at", timeout=2.0) == [("srv/t/h", b"q!", b"at")], 20.0, "a reply")
        # rmw_zenoh's clients query with target ALL_COMPLETE: only a complete queryable answers them.
        assert ros_client.call("srv/t/h", b"q", b"at", timeout=2.0) == [("srv/t/h", b"q!", b"at")]
        assert a.session_id != hub.session_id and int(a.session_id, 16) > 0
    finally:
        ros_client.close()
        for bus in (a, hub):
            bus.close()


@pytest.fixture(scope="module")
def certificates(tmp_path_factory):
    from locnerf_cli.certs import make_certificates

    folder = tmp_path_factory.mktemp("certs")
    make_certificates(folder, roles=("filter",))
    return folder


def test_tls_settings_come_from_the_environment_and_map_onto_zenoh_keys(certificates):
    import json

    from locnerf_services.transport.zenoh_bus import zenoh_config

    environ = {
        "LOCNERF_ZENOH_MODE": "client",
        "LOCNERF_ZENOH_TLS_ROOT_CA": str(certificates / "ca.pem"),
        "LOCNERF_ZENOH_TLS_CERTIFICATE": str(certificates / "filter.pem"),
        "LOCNERF_ZENOH_TLS_KEY": str(certificates / "filter-key.pem"),
        "LOCNERF_ZENOH_TLS_MUTUAL": "true",
    }
    config = TransportConfig().with_environment(environ)
    assert config.tls is not None and config.tls.mutual and config.tls.key.endswith("filter-key.pem")
    conf = zenoh_config(config)
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(conf.get_json("transport/link/tls/connect_certificate")) == str(certificates / "filter.pem")
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) is None  # a client does not listen
    with pytest.raises(ValueError, match="LOCNERF_ZENOH_TLS_MUTUAL='maybe': expected true or false"):
        TransportConfig().with_environment(environ | {"LOCNERF_ZENOH_TLS_MUTUAL": "maybe"})


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"root_ca": "/nonexistent/ca.pem"}, "TLS root_ca '/nonexistent/ca.pem': file not found"),
        ({"key": "ca.pem"}, "expected a PEM private key"),
        ({"certificate": "filter-key.pem"}, "expected a PEM certificate"),
        ({"certificate": "", "key": ""}, "mutual = true: expected a certificate and key"),
    ],
)
def test_bad_tls_files_are_named_in_the_error(certificates, fields, message):
    from locnerf_services.transport.config import TlsConfig

    good = {"root_ca": "ca.pem", "certificate": "filter.pem", "key": "filter-key.pem"}
    paths = {name: (str(certificates / value) if value and not value.startswith("/") else value) for name, value in (good | fields).items()}
    with pytest.raises(ValueError, match=message):
        TlsConfig(**paths)


def test_a_client_started_before_its_router_connects_once_the_router_is_up(caplog):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = TransportConfig(mode="client", connect=(endpoint,)).with_environment({"LOCNERF_ZENOH_CONNECT_RETRY": "30"})
    assert config.connect_retry == 30.0
    opened: list = []
    client = threading.Thread(target=lambda: opened.append(open_bus(config)))
    with caplog.at_level(logging.WARNING, logger="locnerf_services.transport.zenoh_bus"):
        client.start()
        wait_until(lambda: caplog.text.count("not reachable") >= 2, 10.0, "two logged failed tries")
        assert not opened
        router = Router(router_config(ROUTER_FILE, [("listen/endpoints", json.dumps([endpoint]))]))
        client.join(30.0)
    other = open_bus(TransportConfig(mode="client", connect=(endpoint,)))
    try:
        assert len(opened) == 1, "the client did not connect within 30 s of the router coming up"
        got: Inbox[bytes] = Inbox()
        opened[0].subscribe("t/**", lambda _key, payload: got.put(payload))
        deadline, received = time.monotonic() + 20.0, None
        while received is None and time.monotonic() < deadline:
            other.publish("t/1", b"through the late router")
            received = got.get(timeout=0.2)
        assert received == b"through the late router"
    finally:
        for bus in (*opened, other):
            bus.close()
        router.close()


def test_a_client_gives_up_on_an_absent_router_when_its_retry_window_ends():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        open_bus(TransportConfig(mode="client", connect=(endpoint,), connect_retry=1.0))
    assert 1.0 <= time.monotonic() - started < 10.0
