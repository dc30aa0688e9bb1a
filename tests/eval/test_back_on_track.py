"""After a kidnapping: "back on track" (issue 32: within 3 cm / 1° and staying there for 1 s) beside the convergence criterion,
and how long a tracked filter waits for the same hold (the target's ceiling), against a naive scan."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.eval.tracking import BACK_ON_TRACK, ConvergenceConfig, back_on_track_while_tracking, summarize_tracking
from tests.eval.test_tracking import naive_settle_tick, record_from


def test_back_on_track_needs_the_tighter_thresholds_for_a_second():
    # 10 Hz, kidnapping at index 20: 5 cm / 3° from index 24 (converged by 5 cm / 5°), 2 cm / 0.5° from index 30 on,
    # except one 1.2° stamp at index 33, so the first second within 3 cm / 1° starts at index 34.
    translation = [0.01] * 20 + [0.5] * 4 + [0.04] * 6 + [0.02] * 30
    rotation = [0.5] * 20 + [30.0] * 4 + [3.0] * 6 + [0.5] * 3 + [1.2] + [0.5] * 26
    summary = summarize_tracking(record_from(translation, rotation, kidnap_tick=20), ConvergenceConfig())
    assert summary["kidnap"]["seconds_to_converge"] == pytest.approx(0.4)
    assert summary["kidnap"]["back_on_track_s"] == pytest.approx(1.4)
    assert summary["kidnap"]["back_on_track"] == {"translation": 0.03, "rotation_deg": 1.0, "hold": 1.0}
    never = summarize_tracking(record_from(translation, rotation, kidnap_tick=20), ConvergenceConfig(), ConvergenceConfig(translation=0.01, hold=1.0))
    assert never["kidnap"]["back_on_track_s"] is None


def test_a_tracked_filter_waits_for_its_next_hold_as_the_hand_count_says():
    # 10 Hz, 6 s: within from index 0 to 19, out over 20-24, within again from 25. A 1-s hold starts at 0-9 and 25-49;
    # with a 1-s horizon, the 40 instants up to 3.9 s count, and from 1.0-1.4 s (indices 10-14) the next hold is 1.1-1.5 s away.
    translation = [0.01] * 20 + [0.2] * 5 + [0.01] * 35
    record = record_from(translation, [0.5] * 60)
    ceiling = back_on_track_while_tracking(record, 0, 60, BACK_ON_TRACK, horizon=1.0)
    assert ceiling["instants"] == 40 and ceiling["share_within"] == pytest.approx(55 / 60)
    assert ceiling["share_back_within_horizon"] == pytest.approx(35 / 40) and ceiling["longest_wait_s"] == pytest.approx(1.5)
    assert ceiling["median_wait_s"] == 0.0  # 25 of the 40 waits are 0 (indices 0-9 and 25-39 start a hold)
    never = back_on_track_while_tracking(record_from([0.01] * 20 + [0.2] * 40, [0.5] * 60), 0, 60, BACK_ON_TRACK, horizon=1.0)
    assert never["longest_wait_s"] is None and never["share_back_within_horizon"] == pytest.approx(10 / 40)


def test_the_waits_match_a_naive_scan_from_every_instant():
    generator = torch.Generator().manual_seed(5)
    criterion = ConvergenceConfig(translation=0.03, rotation_deg=1.0, hold=0.5)
    for _ in range(100):
        count = int(torch.randint(10, 50, (1,), generator=generator))
        good = torch.rand(count, generator=generator) < 0.8
        record = record_from(torch.where(good, 0.01, 0.2).tolist(), [0.5] * count)
        begin = int(torch.randint(0, count // 2, (1,), generator=generator))
        stamps = record.stamps.tolist()
        waits = []
        for i in range(begin, count):
            if stamps[i] + 1.0 + criterion.hold <= stamps[-1]:
                settled = naive_settle_tick(record, i, count, criterion)
                waits.append(None if settled is None else stamps[settled] - stamps[i])
        ceiling = back_on_track_while_tracking(record, begin, count, criterion, horizon=1.0)
        assert ceiling["instants"] == len(waits)
        if waits:
            assert ceiling["share_back_within_horizon"] == pytest.approx(sum(1 for w in waits if w is not None and w <= 1.0) / len(waits))
            assert ceiling["longest_wait_s"] == (None if None in waits else pytest.approx(max(waits)))
            lower_middle = sorted(waits, key=lambda wait: math.inf if wait is None else wait)[(len(waits) - 1) // 2]
            assert ceiling["median_wait_s"] == (None if lower_middle is None else pytest.approx(lower_middle))


def test_the_start_phase_reports_the_wait_once_converged():
    summary = summarize_tracking(record_from([0.2] * 10 + [0.01] * 90, [0.5] * 100), ConvergenceConfig())
    assert summary["start"]["back_on_track_while_tracking"]["horizon_s"] == 5.0
    assert summary["start"]["back_on_track_while_tracking"]["share_back_within_horizon"] == 1.0
    assert "back_on_track_while_tracking" not in summarize_tracking(record_from([0.2] * 50, [0.5] * 50), ConvergenceConfig())["start"]
