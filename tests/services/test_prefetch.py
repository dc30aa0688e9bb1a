"""The ingest's prefetching producer thread: order, errors, stopping, and its lower priority."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest

from locnerf_services.sensor_ingest.prefetch import PrefetchedEvents


def test_events_come_out_in_order_and_complete():
    with PrefetchedEvents(range(500), depth=4) as events:
        assert list(events) == list(range(500))


def test_the_source_error_is_raised_where_the_source_ended():
    def failing() -> Iterator[int]:
        yield 1
        yield 2
        raise OSError("camera unplugged")

    received = []
    with PrefetchedEvents(failing(), depth=8) as events, pytest.raises(OSError, match="camera unplugged"):
        for event in events:
            received.append(event)
    assert received == [1, 2]


def test_close_stops_an_endless_producer_that_is_waiting_for_room():
    produced = []

    def endless() -> Iterator[int]:
        count = 0
        while True:
            produced.append(count)
            yield count
            count += 1

    prefetched = PrefetchedEvents(endless(), depth=3)
    iterator = iter(prefetched)
    assert [next(iterator) for _ in range(5)] == [0, 1, 2, 3, 4]
    prefetched.close()
    assert not prefetched._thread.is_alive()
    # It ran at most depth + 2 ahead (the queue, the item being offered, the one being produced).
    assert len(produced) <= 5 + 3 + 2


def test_the_producer_thread_runs_at_the_added_niceness_and_the_caller_keeps_its_own():
    before = os.getpriority(os.PRIO_PROCESS, 0)

    def reporting() -> Iterator[tuple[int, int]]:
        yield threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    with PrefetchedEvents(reporting(), nice=3) as events:
        ((thread_id, priority),) = list(events)
    assert thread_id != threading.get_native_id()
    assert priority == min(before + 3, 19)
    assert os.getpriority(os.PRIO_PROCESS, 0) == before


@pytest.mark.parametrize("depth, nice", [(0, 0), (4, -1)])
def test_bad_settings_are_refused(depth, nice):
    with pytest.raises(ValueError, match="expected >= "):
        PrefetchedEvents(range(3), depth=depth, nice=nice)


def test_wait_until_filled_returns_once_depth_events_wait_or_the_source_ended():
    release = threading.Event()

    def gated() -> Iterator[int]:
        yield 0
        release.wait(10)
        yield from range(1, 6)

    with PrefetchedEvents(gated(), depth=3) as events:
        assert not events.wait_until_filled(0.3)  # one event produced, the source waits
        release.set()
        assert events.wait_until_filled(5.0)  # three events wait in the queue
        assert list(events) == list(range(6))
    with PrefetchedEvents(range(2), depth=8) as short:
        assert short.wait_until_filled(5.0)  # the source ended before the queue filled
        assert list(short) == [0, 1]
