"""Real-data views and the success-by-budget curve."""

from __future__ import annotations

import pytest

from locnerf.data import read_llff
from locnerf.eval.paper_logs import read_logged_trials
from locnerf.eval.real_data import logged_views, mean_error_by_budget, seeded_views, success_by_budget, totals


def test_logged_views_match_the_reader_and_carry_offsets(shared_data, generator):
    posed = read_llff(shared_data / "llff" / "fern", downscale=8, split="all")
    trials = read_logged_trials(shared_data / "locnerf_logs" / "global_loc", scene="fern")
    views = logged_views(posed, trials, held_out={0, 8, 16})
    assert [v.frame for v in views] == [2, 3, 7, 15, 18]
    assert all(v.offset is not None and not v.held_out for v in views)
    assert views[0].image.shape == (posed.intrinsics.height, posed.intrinsics.width, 3)
    seeded = seeded_views(posed, 30, generator, held_out={0, 8, 16})
    assert any(v.held_out for v in seeded) and all(v.offset is None for v in seeded)


def test_logged_views_refuse_a_mismatched_data_set(shared_data):
    posed = read_llff(shared_data / "llff" / "fern", downscale=8, split="train")
    trials = read_logged_trials(shared_data / "locnerf_logs" / "global_loc", scene="fern")
    with pytest.raises(ValueError, match="logged frame"):
        logged_views(posed, [t for t in trials if t.frame in (2, 3)] + [trials[0].__class__(**{**trials[0].__dict__, "frame": 16})], held_out=set())


def test_success_by_budget_hand_values():
    curves = [([10, 20, 30], [0.5, 0.04, 0.01], [10.0, 4.0, 1.0]), ([10, 20, 30], [0.5, 0.5, 0.01], [1.0, 1.0, 1.0])]
    assert success_by_budget(curves, [5, 10, 20, 30]) == [0.0, 0.0, 0.5, 1.0]


def test_mean_error_by_budget_hand_values():
    """Each run contributes its latest estimate within the budget; 25 passes sees the 20-pass ones."""
    curves = [([0, 20, 30], [0.5, 0.04, 0.01], [10.0, 4.0, 1.0]), ([0, 10, 40], [0.3, 0.1, 0.02], [2.0, 1.0, 0.5])]
    translation, rotation = mean_error_by_budget(curves, [0, 25, 40])
    assert translation == pytest.approx([0.4, 0.07, 0.015])
    assert rotation == pytest.approx([6.0, 2.5, 0.75])
    with pytest.raises(ValueError, match="budget 5: a run has no estimate within it"):
        mean_error_by_budget([([10], [0.1], [1.0])], [5])


def test_totals_split_held_out_and_logged():
    records = [
        {
            "start": "logged",
            "held_out": False,
            "success": True,
            "translation_error": 0.01,
            "rotation_error_deg": 0.5,
            "seconds": 2.0,
            "original_locnerf": {"success": False, "translation_error": 0.5, "rotation_error_deg": 10.0},
        },
        {"start": "seeded", "held_out": True, "success": False, "translation_error": 0.2, "rotation_error_deg": 9.0, "seconds": 4.0},
    ]
    summary = totals(records)
    assert summary["all"]["success_rate"] == 0.5 and summary["all"]["max_seconds_per_trial"] == 4.0
    assert summary["held_out_views"]["trials"] == 1 and summary["logged_starts"]["success_rate"] == 1.0
    assert summary["original_locnerf_on_logged_starts"]["success_rate"] == 0.0
