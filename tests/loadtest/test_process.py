"""CPU and memory from /proc: a fake /proc with known numbers and an injected clock, and this process itself."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from locnerf.eval.loadtest_process import CLOCK_TICKS_PER_SECOND, ProcessSample, process_usage, read_process_sample


def write_fake_proc(root: Path, pid: int, user_ticks: int, system_ticks: int, rss_kb: int = 102400, peak_kb: int = 204800) -> None:
    """``root/<pid>/stat`` and ``status`` as Linux writes them, with a command name holding spaces and parentheses."""
    folder = root / str(pid)
    folder.mkdir(exist_ok=True)
    rest = ["S"] + ["0"] * 10 + [str(user_ticks), str(system_ticks)] + ["0"] * 30
    (folder / "stat").write_text(f"{pid} (python -m (x) y) " + " ".join(rest) + "\n")
    (folder / "status").write_text(f"Name:\tpython\nThreads:\t7\nVmHWM:\t  {peak_kb} kB\nVmRSS:\t  {rss_kb} kB\n")


def test_fields_are_read_after_a_command_name_with_spaces_and_parentheses(tmp_path):
    write_fake_proc(tmp_path, 42, 3 * CLOCK_TICKS_PER_SECOND, CLOCK_TICKS_PER_SECOND)
    sample = read_process_sample(42, proc_root=tmp_path, clock=lambda: 12.5)
    assert sample.cpu_seconds == pytest.approx(4.0)
    assert (sample.pid, sample.at, sample.rss_mb, sample.peak_rss_mb, sample.threads) == (42, 12.5, 100.0, 200.0, 7)


def test_usage_is_the_cpu_time_used_between_two_samples_over_the_clock_time_between_them(tmp_path):
    clock = iter([10.0, 12.0]).__next__
    write_fake_proc(tmp_path, 42, user_ticks=100, system_ticks=50)
    before = read_process_sample(42, proc_root=tmp_path, clock=clock)
    # 1.5 CPU seconds (user 1, system 0.5) in 2 clock seconds: three quarters of a core.
    write_fake_proc(tmp_path, 42, user_ticks=100 + CLOCK_TICKS_PER_SECOND, system_ticks=50 + CLOCK_TICKS_PER_SECOND // 2, rss_kb=51200, peak_kb=307200)
    usage = process_usage(before, read_process_sample(42, proc_root=tmp_path, clock=clock))
    assert usage == {"pid": 42, "cpu_percent": 75.0, "rss_mb": 50.0, "peak_rss_mb": 300.0, "threads": 7}


def test_this_process_is_read_from_proc():
    sample = read_process_sample(os.getpid(), clock=lambda: 5.0)
    assert (sample.pid, sample.at) == (os.getpid(), 5.0)
    assert sample.rss_mb > 10.0 and sample.peak_rss_mb >= sample.rss_mb and sample.threads >= 1
    assert sample.cpu_seconds > 0.0
    assert read_process_sample(os.getpid()).cpu_seconds >= sample.cpu_seconds


def test_bad_inputs_name_the_problem(tmp_path):
    with pytest.raises(ProcessLookupError, match="process 999"):
        read_process_sample(999, proc_root=tmp_path)
    first = ProcessSample(pid=1, at=1.0, cpu_seconds=0.0, rss_mb=1.0, peak_rss_mb=1.0, threads=1)
    with pytest.raises(ValueError, match="different processes"):
        process_usage(first, ProcessSample(pid=2, at=2.0, cpu_seconds=0.0, rss_mb=1.0, peak_rss_mb=1.0, threads=1))
    with pytest.raises(ValueError, match="after the first"):
        process_usage(first, first)
