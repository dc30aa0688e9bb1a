"""The Zenoh implementation of the Bus: the only module of the project that imports zenoh."""

from __future__ import annotations

import json
import logging
import time

import zenoh

from locnerf_services.transport.bus import AttachedCallback, LivelinessCallback, QueryHandler, Reply, SampleCallback
from locnerf_services.transport.config import TlsConfig, TransportConfig

logger = logging.getLogger(__name__)

RETRY_FIRST, RETRY_LONGEST = 0.25, 5.0  # seconds between tries of an unreachable router: doubling from the first to the longest


def open_session(config: TransportConfig) -> zenoh.Session:
    """``zenoh.open`` of ``config``; in client mode, retried for ``config.connect_retry`` seconds while
    the router is unreachable (zenoh.ZError), with a doubling backoff and a warning per failure.

    Raises:
        zenoh.ZError: the last failure, once the retry window has passed (at once with connect_retry 0).
    """
    deadline = time.monotonic() + (config.connect_retry if config.mode == "client" else 0.0)
    delay, attempt = RETRY_FIRST, 1
    while True:
        try:
            session = zenoh.open(zenoh_config(config))
        except zenoh.ZError as error:
            left = deadline - time.monotonic()
            if left <= 0:
                raise
            wait = min(delay, left)
            logger.warning(
                "router %s not reachable (try %d: %s); retrying in %.2f s, giving up in %.0f s", ",".join(config.connect), attempt, error, wait, left
            )
            time.sleep(wait)
            delay, attempt = min(2 * delay, RETRY_LONGEST), attempt + 1
            continue
        if attempt > 1:
            logger.info("connected to router %s after %d tries", ",".join(config.connect), attempt)
        return session


def zenoh_config(config: TransportConfig) -> zenoh.Config:
    """A zenoh.Config from our TransportConfig."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(config.mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(config.multicast_scouting))
    conf.insert_json5("connect/endpoints", json.dumps(list(config.connect)))
    if config.mode == "peer":
        conf.insert_json5("listen/endpoints", json.dumps(list(config.listen)))
    if config.tls is not None:
        apply_tls(conf, config.tls, listens=config.mode == "peer")
    return conf


def apply_tls(conf: zenoh.Config, tls: TlsConfig, listens: bool) -> None:
    """Set zenoh's ``transport/link/tls`` keys (zenoh 1.x names) from ``tls``.

    The certificate is this process's identity both as a listener (``listen_*``, only when the
    session listens) and, with mutual TLS, as a connecting client (``connect_*``)."""
    settings: dict[str, object] = {"root_ca_certificate": tls.root_ca, "enable_mtls": tls.mutual}
    if tls.certificate:
        if listens:
            settings |= {"listen_certificate": tls.certificate, "listen_private_key": tls.key}
        if tls.mutual:
            settings |= {"connect_certificate": tls.certificate, "connect_private_key": tls.key}
    for name, value in settings.items():
        conf.insert_json5(f"transport/link/tls/{name}", json.dumps(value))


class _Undeclare:
    def __init__(self, entity) -> None:
        self._entity = entity

    def close(self) -> None:
        if self._entity is not None:
            self._entity.undeclare()
            self._entity = None


def _safe(callback: SampleCallback, sample: zenoh.Sample) -> None:
    try:
        callback(str(sample.key_expr), sample.payload.to_bytes())
    except Exception:  # a faulty callback must not take the Zenoh thread down
        logger.exception("subscriber callback failed on %s", sample.key_expr)


def _safe_attached(callback: AttachedCallback, sample: zenoh.Sample) -> None:
    try:
        attachment = sample.attachment
        callback(str(sample.key_expr), sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes())
    except Exception:
        logger.exception("subscriber callback failed on %s", sample.key_expr)


def _answer(handler: QueryHandler, query: zenoh.Query) -> None:
    try:
        payload, attachment = query.payload, query.attachment
        replies = handler(str(query.key_expr), b"" if payload is None else payload.to_bytes(), None if attachment is None else attachment.to_bytes())
        for key, reply, reply_attachment in replies:
            query.reply(key, reply, attachment=reply_attachment)
    except Exception:  # a faulty handler must not take the Zenoh thread down
        logger.exception("queryable handler failed on %s", query.key_expr)


class ZenohBus:
    """A Zenoh session behind the Bus protocol.

    Args:
        config: mode, endpoints and how long a client retries an unreachable router.
    """

    def __init__(self, config: TransportConfig) -> None:
        self.config = config
        self._session = open_session(config)
        self._publishers: dict[str, zenoh.Publisher] = {}

    @property
    def session_id(self) -> str:
        return str(self._session.info.zid())

    def publish(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        publisher = self._publishers.get(key)
        if publisher is None:
            congestion = zenoh.CongestionControl.BLOCK if self.config.block_when_congested else zenoh.CongestionControl.DROP
            publisher = self._publishers[key] = self._session.declare_publisher(key, congestion_control=congestion)
        publisher.put(payload, attachment=attachment)

    def subscribe(self, key_expr: str, callback: SampleCallback) -> _Undeclare:
        return _Undeclare(self._session.declare_subscriber(key_expr, lambda sample: _safe(callback, sample)))

    def subscribe_attached(self, key_expr: str, callback: AttachedCallback) -> _Undeclare:
        return _Undeclare(self._session.declare_subscriber(key_expr, lambda sample: _safe_attached(callback, sample)))

    def declare_queryable(self, key_expr: str, handler: QueryHandler, complete: bool = False) -> _Undeclare:
        return _Undeclare(self._session.declare_queryable(key_expr, lambda query: _answer(handler, query), complete=complete))

    def query(self, key: str, payload: bytes, attachment: bytes | None = None, timeout: float = 5.0) -> list[Reply]:
        replies: list[Reply] = []
        for reply in self._session.get(key, payload=payload, attachment=attachment, timeout=timeout):
            if reply.ok is not None:
                sample = reply.ok
                replies.append((str(sample.key_expr), sample.payload.to_bytes(), None if sample.attachment is None else sample.attachment.to_bytes()))
        return replies

    def declare_token(self, key: str) -> _Undeclare:
        return _Undeclare(self._session.liveliness().declare_token(key))

    def watch_liveliness(self, key_expr: str, callback: LivelinessCallback) -> _Undeclare:
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            except Exception:
                logger.exception("liveliness callback failed on %s", sample.key_expr)

        return _Undeclare(self._session.liveliness().declare_subscriber(key_expr, on_sample, history=True))

    def close(self) -> None:
        for publisher in self._publishers.values():
            publisher.undeclare()
        self._publishers.clear()
        self._session.close()
