"""A bounded inbox with priority lanes: the filter thread takes odometry before any other message.

Zenoh callbacks ``put`` into a lane and never block; the filter thread's ``get`` returns the oldest
item of the most urgent non-empty lane (lane 0 first). Each lane is a bounded FIFO that drops its
oldest item when full and counts the drop, like :class:`services.transport.Inbox`.
"""

from __future__ import annotations

import collections
import threading
from typing import Generic, TypeVar

Item = TypeVar("Item")


class LaneInbox(Generic[Item]):
    """FIFO lanes served in priority order.

    Args:
        lanes: number of lanes; lane 0 is the most urgent.
        capacity: items kept per lane.
    """

    def __init__(self, lanes: int, capacity: int = 256) -> None:
        if lanes < 1:
            raise ValueError(f"lanes {lanes}: expected >= 1")
        if capacity < 1:
            raise ValueError(f"lane capacity {capacity}: expected >= 1")
        self._lanes: list[collections.deque[Item]] = [collections.deque(maxlen=capacity) for _ in range(lanes)]
        self._ready = threading.Condition()
        self.dropped = 0

    def put(self, lane: int, item: Item) -> None:
        """Append ``item`` to ``lane`` (called from transport threads; never blocks).

        Raises:
            IndexError: ``lane`` is not in ``[0, lanes)``.
        """
        if not 0 <= lane < len(self._lanes):
            raise IndexError(f"lane {lane}: expected 0 to {len(self._lanes) - 1}")
        with self._ready:
            queue = self._lanes[lane]
            if len(queue) == queue.maxlen:
                self.dropped += 1
            queue.append(item)
            self._ready.notify()

    def get(self, timeout: float) -> Item | None:
        """The oldest item of the most urgent non-empty lane, waiting up to ``timeout`` seconds."""
        with self._ready:
            if not any(self._lanes):
                self._ready.wait(timeout)
            for queue in self._lanes:
                if queue:
                    return queue.popleft()
            return None

    def waiting(self, lane: int) -> int:
        """Items queued in ``lane`` now."""
        with self._ready:
            return len(self._lanes[lane])
