"""Shared fixtures (seeded generators, the path of the read-only shared data) and the ``serial`` marker.

``make test`` runs the suite in two parts: the tests that start services or measure real time
(marked ``serial`` here, by folder or by ``live`` in their name) alone, after the others have run
on two pytest-xdist workers. A worker runs torch, OpenMP and numba on one thread each, so that two
workers share two cores without oversubscribing them.
"""

from __future__ import annotations

import os
from pathlib import Path

if os.environ.get("PYTEST_XDIST_WORKER"):
    # Before numba and the processes the tests start read them.
    os.environ.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")

import pytest
import torch

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"
TESTS = Path(__file__).resolve().parent
SERIAL_PATHS = ("integration", "loadtest", "test_tutorial.py")
"""Folders and files under tests/ whose tests start the service processes or time real-time behaviour (the
service-logic tests under tests/services, on the in-memory bus or a single Zenoh session, wait with generous
timeouts and assert no rates: they run on the workers)."""


def pytest_configure(config: pytest.Config) -> None:
    if os.environ.get("PYTEST_XDIST_WORKER"):
        torch.set_num_threads(1)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark ``serial`` every test under SERIAL_PATHS and every test with ``live`` in its name."""
    for item in items:
        relative = Path(item.path).resolve().relative_to(TESTS)
        if relative.parts[0] in SERIAL_PATHS or "live" in item.name:
            item.add_marker(pytest.mark.serial)


@pytest.fixture
def generator() -> torch.Generator:
    """A CPU generator seeded identically for every test."""
    return torch.Generator().manual_seed(1234)


@pytest.fixture
def shared_data() -> Path:
    """Path of ../shared/data; tests that need it are skipped with a reason when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA
