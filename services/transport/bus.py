"""The Bus protocol that services talk through, and the receive-side inboxes.

A bus publishes bytes on keys, delivers subscribed samples to callbacks, and tracks liveliness
tokens. Callbacks run on the transport's threads: they must only enqueue, never block or compute;
:class:`Inbox` (bounded FIFO, oldest dropped when full) and :class:`LatestSlot` (keeps only the
newest item, the ring channel of 1 for images) are the two places they enqueue into.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

Item = TypeVar("Item")
SampleCallback = Callable[[str, bytes], None]
AttachedCallback = Callable[[str, bytes, bytes | None], None]
LivelinessCallback = Callable[[str, bool], None]
Reply = tuple[str, bytes, bytes | None]
QueryHandler = Callable[[str, bytes, bytes | None], list[Reply]]


class Closeable(Protocol):
    """A subscription or token; closing undeclares it."""

    def close(self) -> None: ...


class Bus(Protocol):
    """What a service needs of the middleware."""

    @property
    def session_id(self) -> str:
        """The session's id, lowercase hex (rmw_zenoh puts it in its liveliness tokens)."""

    def publish(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        """Send ``payload`` (and an optional ``attachment``) on ``key`` (never blocks on slow subscribers)."""

    def subscribe(self, key_expr: str, callback: SampleCallback) -> Closeable:
        """Call ``callback(key, payload)`` for every sample matching ``key_expr``."""

    def subscribe_attached(self, key_expr: str, callback: AttachedCallback) -> Closeable:
        """Call ``callback(key, payload, attachment or None)`` for every sample matching ``key_expr``."""

    def declare_queryable(self, key_expr: str, handler: QueryHandler, complete: bool = False) -> Closeable:
        """Answer queries matching ``key_expr``: ``handler(key, payload, attachment)`` returns the
        replies ``(key, payload, attachment)``; it runs on a transport thread, so it must be quick.
        ``complete``: the queryable answers for every key that ``key_expr`` matches (Zenoh's
        ``complete``); queries with target ALL_COMPLETE, as rmw_zenoh's service clients send, reach
        only complete queryables."""

    def query(self, key: str, payload: bytes, attachment: bytes | None = None, timeout: float = 5.0) -> list[Reply]:
        """Send a query and collect the successful replies until ``timeout`` seconds or the last one."""

    def declare_token(self, key: str) -> Closeable:
        """Announce liveliness on ``key`` until closed or until the process dies."""

    def watch_liveliness(self, key_expr: str, callback: LivelinessCallback) -> Closeable:
        """``callback(key, alive)`` for tokens matching ``key_expr``, current ones included."""

    def close(self) -> None:
        """Release the session."""


class Inbox(Generic[Item]):
    """Bounded FIFO for callbacks: ``put`` never blocks; when full the oldest item is dropped.

    Args:
        capacity: items kept.
    """

    def __init__(self, capacity: int = 256) -> None:
        if capacity < 1:
            raise ValueError(f"inbox capacity {capacity}: expected >= 1")
        self._items: collections.deque[Item] = collections.deque(maxlen=capacity)
        self._ready = threading.Condition()
        self.dropped = 0

    def put(self, item: Item) -> None:
        """Append (called from transport threads)."""
        with self._ready:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self._ready.notify()

    def get(self, timeout: float) -> Item | None:
        """The oldest item, waiting up to ``timeout`` seconds; None if nothing arrived."""
        with self._ready:
            if not self._items:
                self._ready.wait(timeout)
            return self._items.popleft() if self._items else None


class LatestSlot(Generic[Item]):
    """Holds only the newest item: a ring channel of capacity 1."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: Item | None = None
        self.received = 0
        self.replaced = 0

    def put(self, item: Item) -> None:
        """Replace the held item (called from transport threads)."""
        with self._lock:
            self.received += 1
            if self._item is not None:
                self.replaced += 1
            self._item = item

    def take(self) -> Item | None:
        """The newest item, or None; the slot is empty afterwards."""
        with self._lock:
            item, self._item = self._item, None
            return item
