"""Service tests run in one process beside other jobs on few cores: one torch thread (see
``services.runtime.limit_torch_threads`` for the measured reason)."""

from __future__ import annotations

import pytest

from locnerf_services.runtime import limit_torch_threads


@pytest.fixture(autouse=True, scope="package")
def _one_torch_thread() -> None:
    limit_torch_threads(1)
