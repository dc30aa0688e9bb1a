"""CPU time and memory of running processes, read from ``/proc`` (Linux).

``/proc/<pid>/stat`` gives user and system CPU time in clock ticks (fields 14 and 15);
``/proc/<pid>/status`` gives the resident set (``VmRSS``), its peak (``VmHWM``) and ``Threads``.
Two samples of one process give its CPU use over the interval between them.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

CLOCK_TICKS_PER_SECOND = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ProcessSample:
    """One reading of a process: CPU seconds used so far, memory now and at its peak."""

    pid: int
    at: float
    cpu_seconds: float
    rss_mb: float
    peak_rss_mb: float
    threads: int


def read_process_sample(pid: int, proc_root: Path = Path("/proc"), clock: Callable[[], float] = time.monotonic) -> ProcessSample:
    """Read ``pid``'s CPU time and memory now; ``clock`` (monotonic seconds) stamps the sample.

    Raises:
        ProcessLookupError: the process does not exist (any more).
    """
    folder = proc_root / str(pid)
    try:
        stat = (folder / "stat").read_text()
        status = (folder / "status").read_text()
    except FileNotFoundError:
        raise ProcessLookupError(f"process {pid}: no {folder} (not running)") from None
    # The command name (field 2) is in parentheses and may contain spaces: split after the last ')'.
    fields = stat[stat.rindex(")") + 2 :].split()
    user_ticks, system_ticks = int(fields[11]), int(fields[12])
    values = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)

    def kilobytes(name: str) -> float:
        return float(values.get(name, "0 kB").split()[0])

    return ProcessSample(
        pid=pid,
        at=clock(),
        cpu_seconds=(user_ticks + system_ticks) / CLOCK_TICKS_PER_SECOND,
        rss_mb=kilobytes("VmRSS") / 1024.0,
        peak_rss_mb=kilobytes("VmHWM") / 1024.0,
        threads=int(values.get("Threads", "0").strip()),
    )


def process_usage(before: ProcessSample, after: ProcessSample) -> dict[str, float]:
    """CPU use between two samples of one process (100 = one core busy) and memory at ``after``."""
    if before.pid != after.pid:
        raise ValueError(f"samples of different processes ({before.pid}, {after.pid}): expected one pid")
    elapsed = after.at - before.at
    if elapsed <= 0:
        raise ValueError(f"sample interval {elapsed} s: expected the second sample after the first")
    return {
        "pid": after.pid,
        "cpu_percent": round(100.0 * (after.cpu_seconds - before.cpu_seconds) / elapsed, 1),
        "rss_mb": round(after.rss_mb, 1),
        "peak_rss_mb": round(after.peak_rss_mb, 1),
        "threads": after.threads,
    }
