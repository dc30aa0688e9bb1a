"""An in-process bus for unit tests: synchronous delivery, Zenoh-like ``*``/``**`` key matching."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from locnerf_services.transport.bus import AttachedCallback, LivelinessCallback, QueryHandler, Reply, SampleCallback


def key_matches(key_expr: str, key: str) -> bool:
    """Whether ``key`` matches ``key_expr`` (``*`` one chunk, ``**`` any number of chunks)."""

    def match(pattern: list[str], chunks: list[str]) -> bool:
        if not pattern:
            return not chunks
        if pattern[0] == "**":
            return any(match(pattern[1:], chunks[i:]) for i in range(len(chunks) + 1))
        return bool(chunks) and (pattern[0] == "*" or pattern[0] == chunks[0]) and match(pattern[1:], chunks[1:])

    return match(key_expr.split("/"), key.split("/"))


@dataclass
class _Registration:
    bus: MemoryBus
    table: list
    entry: tuple

    def close(self) -> None:
        with self.bus._lock:
            if self.entry in self.table:
                self.table.remove(self.entry)
                if self.table is self.bus._tokens:
                    self.bus._notify_liveliness(self.entry[0], False)


@dataclass
class MemoryBus:
    """All services of a test share one instance; callbacks run inside ``publish``."""

    _subscribers: list = field(default_factory=list)
    _queryables: list = field(default_factory=list)
    _tokens: list = field(default_factory=list)
    _watchers: list = field(default_factory=list)
    _lock: threading.RLock = field(default_factory=threading.RLock)

    session_id: str = "0123456789abcdef0123456789abcdef"

    def publish(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        with self._lock:
            targets = [callback for pattern, callback in self._subscribers if key_matches(pattern, key)]
        for callback in targets:
            callback(key, bytes(payload), attachment)

    def subscribe(self, key_expr: str, callback: SampleCallback) -> _Registration:
        return self.subscribe_attached(key_expr, lambda key, payload, _attachment: callback(key, payload))

    def subscribe_attached(self, key_expr: str, callback: AttachedCallback) -> _Registration:
        entry = (key_expr, callback)
        with self._lock:
            self._subscribers.append(entry)
        return _Registration(self, self._subscribers, entry)

    def declare_queryable(self, key_expr: str, handler: QueryHandler, complete: bool = False) -> _Registration:
        """As :meth:`Bus.declare_queryable`; ``complete`` changes nothing here: the in-memory queries
        reach every matching queryable, as Zenoh's default query target does."""
        entry = (key_expr, handler)
        with self._lock:
            self._queryables.append(entry)
        return _Registration(self, self._queryables, entry)

    def query(self, key: str, payload: bytes, attachment: bytes | None = None, timeout: float = 5.0) -> list[Reply]:
        with self._lock:
            handlers = [handler for pattern, handler in self._queryables if key_matches(pattern, key)]
        return [reply for handler in handlers for reply in handler(key, bytes(payload), attachment)]

    def declare_token(self, key: str) -> _Registration:
        entry = (key, object())
        with self._lock:
            self._tokens.append(entry)
            self._notify_liveliness(key, True)
        return _Registration(self, self._tokens, entry)

    def watch_liveliness(self, key_expr: str, callback: LivelinessCallback) -> _Registration:
        entry = (key_expr, callback)
        with self._lock:
            self._watchers.append(entry)
            for token_key, _ in self._tokens:
                if key_matches(key_expr, token_key):
                    callback(token_key, True)
        return _Registration(self, self._watchers, entry)

    def _notify_liveliness(self, key: str, alive: bool) -> None:
        for pattern, callback in list(self._watchers):
            if key_matches(pattern, key):
                callback(key, alive)

    def close(self) -> None:
        with self._lock:
            self._subscribers.clear()
            self._queryables.clear()
            self._watchers.clear()
            self._tokens.clear()
