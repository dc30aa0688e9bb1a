"""Saving the filter's last pose off the pose path: a writer thread fed a newest-only slot.

The filter thread :meth:`StateWriter.offer` s an immutable :class:`SavedPose` with every pose it
publishes (a slot assignment, it never waits for the disk); the writer thread writes the newest
offer at most ``rate`` times per second. A failing write (read-only or missing folder, full disk)
is logged (the first one, then every 100th) and counted in :attr:`StateWriter.failures`; the
pose stream never sees it. The writer never touches the filter: it only reads the offered copies.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path

from locnerf_services.filter_loop.state_file import SavedPose, save_pose
from locnerf_services.transport import LatestSlot

logger = logging.getLogger(__name__)

_LOG_EVERY = 100


class StateWriter:
    """Writes the newest offered pose to ``path`` at most ``rate`` times per second, on its own thread.

    Args:
        path: the state file.
        rate: saves per second at most (> 0).
        save: writes one pose to a path (injectable for tests); raises ``OSError`` on failure.
    """

    def __init__(self, path: Path, rate: float, save: Callable[[Path, SavedPose], None] = save_pose) -> None:
        if rate <= 0:
            raise ValueError(f"state save rate {rate}: expected > 0 saves per second")
        self.path = path
        self.period = 1.0 / rate
        self._save = save
        self._slot: LatestSlot[SavedPose] = LatestSlot()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.saved = 0
        self.failures = 0
        self._thread = threading.Thread(target=self._run, name="state-writer", daemon=True)
        self._thread.start()

    def offer(self, pose: SavedPose) -> None:
        """Hand over the newest pose (called by the filter thread; never blocks on the disk)."""
        self._slot.put(pose)
        self._wake.set()

    def _write(self, pose: SavedPose) -> None:
        try:
            self._save(self.path, pose)
            self.saved += 1
        except OSError as error:
            if self.failures % _LOG_EVERY == 0:
                logger.warning("cannot save the filter state to %s (%d failures so far): %s", self.path, self.failures + 1, error)
            self.failures += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait()
            self._wake.clear()
            pose = self._slot.take()
            if pose is not None:
                self._write(pose)
            self._stop.wait(self.period)

    def close(self) -> None:
        """Stop the thread and write the newest pose not yet written (once)."""
        self._stop.set()
        self._wake.set()
        self._thread.join()
        pose = self._slot.take()
        if pose is not None:
            self._write(pose)
