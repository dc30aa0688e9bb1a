"""Scoring a live run (locnerf.eval.tracking_live) on hand-made observations."""

from __future__ import annotations

import math

import pytest
import torch

from locnerf.eval.tracking import ConvergenceConfig
from locnerf.eval.tracking_live import LiveObservations, live_rates, live_record, live_summary
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, so3_exp


def observations(count: int = 30, slow: float = 1.0) -> LiveObservations:
    """Odometry at 15 Hz arriving ``slow`` times slower than real time; poses 10 ms after it,
    off by 0.01 m along x and 1° about y; an update result every 3rd stamp."""
    observed = LiveObservations()
    rotation = so3_exp(torch.tensor([0.0, math.radians(1.0), 0.0], dtype=torch.float64))
    for k in range(count):
        stamp, arrival = k / 15, 100 + slow * k / 15
        truth = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.1 * k, 0.0, 0.0], dtype=torch.float64))
        observed.odometry.append((stamp, arrival))
        observed.truth[stamp] = truth
        observed.poses.append((stamp, arrival + 0.01, make_pose(rotation, truth[:3, 3] + torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64))))
        if k % 3 == 0:
            observed.updates[f"u{k}"] = arrival + 0.02
    return observed


def test_errors_are_in_map_units_and_updates_sit_at_the_last_pose_before_them():
    record = live_record(observations(), MapNormalization(scale=2.0), kidnap_at=1.0)
    assert torch.allclose(record.translation_error, torch.full((30,), 0.02, dtype=torch.float64))
    assert torch.allclose(record.rotation_error_deg, torch.full((30,), 1.0, dtype=torch.float64))
    assert record.update_ticks == list(range(0, 30, 3))  # result 10 ms after the pose of its stamp
    assert record.kidnap_tick == 15  # first stamp at or after 1.0 s


def test_rates_are_measured_from_arrivals():
    rates = live_rates(observations(slow=2.0))
    assert rates["realtime_factor"] == pytest.approx(0.5)
    assert rates["pose_realtime_factor"] == pytest.approx(0.5)
    assert rates["pose_hz"] == pytest.approx(7.5)
    assert rates["update_hz"] == pytest.approx(10 / (2 * 29 / 15))
    assert rates["pose_latency_p50_ms"] == pytest.approx(10.0)


def test_summary_carries_the_headline_figures():
    summary = live_summary(observations(), MapNormalization(), 1.0, ConvergenceConfig(hold=0.5))
    assert summary["converged_after_s"] == 0.0 and summary["translation_median"] == pytest.approx(0.01)
    assert summary["kidnap_recovery_updates"] == 1  # the update on the kidnap stamp itself
    assert summary["realtime_factor"] == pytest.approx(1.0)
    assert "series" not in summary
    series = live_summary(observations(), MapNormalization(), 1.0, ConvergenceConfig(hold=0.5), series=True)["series"]
    record = live_record(observations(), MapNormalization(), 1.0)
    assert series["stamps"] == record.stamps.tolist() and series["translation_error"] == record.translation_error.tolist()


def test_nothing_to_score_is_refused():
    observed = observations()
    observed.truth.clear()
    with pytest.raises(ValueError, match="ground truth"):
        live_record(observed, MapNormalization(), None)
