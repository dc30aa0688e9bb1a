"""CPU and memory from /proc: a fake /proc with known numbers, and this process itself."""

from __future__ import annotations

import os
import time

import pytest

from locnerf.eval.loadtest_process import CLOCK_TICKS_PER_SECOND, ProcessSample, process_usage, read_process_sample


def test_fields_are_read_after_a_command_name_with_spaces_and_parentheses(tmp_path):
    folder = tmp_path / "42"
    folder.mkdir()
    rest = ["S"] + ["0"] * 10 + [str(3 * CLOCK_TICKS_PER_SECOND), str(CLOCK_TICKS_PER_SECOND)] + ["0"] * 30
    (folder / "stat").write_text("42 (python -m (x) y) " + " ".join(rest) + "\n")
    (folder / "status").write_text("Name:\tpython\nThreads:\t7\nVmHWM:\t  204800 kB\nVmRSS:\t  102400 kB\n")
    sample = read_process_sample(42, proc_root=tmp_path)
    assert sample.cpu_seconds == pytest.approx(4.0)
    assert (sample.rss_mb, sample.peak_rss_mb, sample.threads) == (100.0, 200.0, 7)


def test_usage_of_a_busy_loop_is_near_one_core():
    before = read_process_sample(os.getpid())
    deadline = time.monotonic() + 0.5
    while time.monotonic() < deadline:
        pass
    usage = process_usage(before, read_process_sample(os.getpid()))
    # 2-core machine shared with other jobs: the loop gets at least a third of a core, at most one.
    assert 33.0 <= usage["cpu_percent"] <= 110.0
    assert usage["rss_mb"] > 10.0


def test_bad_inputs_name_the_problem(tmp_path):
    with pytest.raises(ProcessLookupError, match="process 999"):
        read_process_sample(999, proc_root=tmp_path)
    first = ProcessSample(pid=1, at=1.0, cpu_seconds=0.0, rss_mb=1.0, peak_rss_mb=1.0, threads=1)
    with pytest.raises(ValueError, match="different processes"):
        process_usage(first, ProcessSample(pid=2, at=2.0, cpu_seconds=0.0, rss_mb=1.0, peak_rss_mb=1.0, threads=1))
    with pytest.raises(ValueError, match="after the first"):
        process_usage(first, first)
