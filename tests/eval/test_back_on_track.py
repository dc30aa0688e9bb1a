"""After a kidnapping: "back on track" (issue 32: within 3 cm / 1° and staying there for 1 s) beside the convergence criterion."""

from __future__ import annotations

import pytest

from locnerf.eval.tracking import ConvergenceConfig, summarize_tracking
from tests.eval.test_tracking import record_from


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
