"""Produce a source's events ahead of their release, in a background thread of lower CPU priority.

A source that renders its frames (the procedural world, a replay that decodes and corrupts
images) spends tens of milliseconds per frame. Produced inline, that work delays the odometry
released after it; produced by :class:`PrefetchedEvents` up to ``depth`` events ahead, it is done
while the pacer sleeps, and with ``nice`` > 0 the producing thread yields the CPU to the pacer, the
filter and the pose stream when they share the machine (Linux gives each thread its own niceness).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
from collections.abc import Iterable, Iterator
from typing import Generic, TypeVar

logger = logging.getLogger(__name__)

Event = TypeVar("Event")

_END = object()


class _Failure:
    """The exception that ended the producer, handed to the consumer to re-raise."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


class PrefetchedEvents(Generic[Event]):
    """Iterate ``events`` through a bounded queue filled by a producer thread.

    Args:
        events: the source (consumed only by the producer thread).
        depth: most events produced ahead of the consumer (>= 1).
        nice: niceness added to the producer thread (0: same priority as the caller).

    The iterator yields the events in order and re-raises the source's exception, if any, where
    the source ended. :meth:`close` (or leaving a ``with`` block) stops the producer.
    """

    def __init__(self, events: Iterable[Event], depth: int = 32, nice: int = 0) -> None:
        if depth < 1:
            raise ValueError(f"prefetch depth {depth}: expected >= 1")
        if nice < 0:
            raise ValueError(f"producer niceness {nice}: expected >= 0 (only lowering the priority needs no privileges)")
        self._queue: queue.Queue[object] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._filled = threading.Event()
        self._nice = nice
        self._thread = threading.Thread(target=self._produce, args=(iter(events),), name="ingest-prefetch", daemon=True)
        self._thread.start()

    def _produce(self, events: Iterator[Event]) -> None:
        if self._nice:
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, 0) + self._nice)
            except OSError as error:
                logger.warning("prefetch thread keeps its priority: %s", error)
        try:
            for event in events:
                if not self._offer(event):
                    return
            self._offer(_END)
        except BaseException as error:  # noqa: BLE001 - handed to the consumer, which re-raises it
            self._offer(_Failure(error))
        finally:
            self._filled.set()

    def _offer(self, item: object) -> bool:
        """Queue ``item``, waiting for room; False once closed."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                if self._queue.full():
                    self._filled.set()
                return True
            except queue.Full:
                continue
        return False

    def wait_until_filled(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s until ``depth`` events wait in the queue or the source has
        ended; whether that happened."""
        return self._filled.wait(timeout)

    def __iter__(self) -> Iterator[Event]:
        while True:
            item = self._queue.get()
            if item is _END:
                return
            if isinstance(item, _Failure):
                raise item.error
            yield item  # type: ignore[misc]

    def close(self, timeout: float = 5.0) -> None:
        """Stop the producer and wait up to ``timeout`` s for it (it finishes the event it is producing)."""
        self._stop.set()
        self._thread.join(timeout)
        if self._thread.is_alive():
            logger.warning("prefetch thread still producing after %.0f s; left to end with the process", timeout)

    def __enter__(self) -> PrefetchedEvents[Event]:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
