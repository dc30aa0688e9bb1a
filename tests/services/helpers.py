"""Small helpers shared by the service and integration tests."""

from __future__ import annotations

import time
from collections.abc import Callable

from locnerf_services.supervisor import free_port

__all__ = ["free_port", "wait_until"]


def wait_until(condition: Callable[[], bool], timeout: float, what: str, poll: float = 0.05) -> None:
    """Poll ``condition`` until true; fail the test naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)
