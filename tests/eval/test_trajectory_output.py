"""A tracking run's TUM files: the headline's stretch, and after a kidnapping the recovery."""

from __future__ import annotations

from pathlib import Path

import torch

from locnerf.data.trajectory_files import read_trajectory
from locnerf.eval.tracking import ConvergenceConfig, TrackingRecord
from locnerf.eval.trajectory_output import write_run_trajectories
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, so3_exp


def _record(kidnap_tick: int | None) -> TrackingRecord:
    """Ten stamps at 10 Hz, the estimate on the truth (converged at once), each pose its own."""
    stamps = torch.arange(10, dtype=torch.float64) / 10
    poses = torch.stack(
        [make_pose(so3_exp(torch.tensor([0.0, 0.1 * k, 0.0], dtype=torch.float64)), torch.tensor([0.1 * k, 0.0, 1.0], dtype=torch.float64)) for k in range(10)]
    )
    zeros = torch.zeros(10, dtype=torch.float64)
    return TrackingRecord(stamps, zeros, zeros, list(range(10)), kidnap_tick, 1.0, poses, poses.clone())


def test_a_kidnapped_run_writes_the_estimate_from_the_jump_on(tmp_path: Path):
    """``estimate.txt`` stops at the kidnapping's tick and ``estimate_after_kidnap.txt`` holds every estimate from it to
    the end, at their stamps (the record is the oracle); a run without a kidnapping writes no such file."""
    record = _record(kidnap_tick=6)
    written = write_run_trajectories(tmp_path / "k", record, MapNormalization(), ConvergenceConfig(hold=0.0), torch.zeros(0), torch.zeros(0, 4, 4))
    before, after = read_trajectory(written["estimate"]), read_trajectory(written["estimate_after_kidnap"])
    torch.testing.assert_close(torch.as_tensor(after.stamps, dtype=torch.float64), record.stamps[6:])
    torch.testing.assert_close(after.poses.double(), record.estimates[6:])
    assert len(before.stamps) == 6
    plain = write_run_trajectories(
        tmp_path / "p", _record(kidnap_tick=None), MapNormalization(), ConvergenceConfig(hold=0.0), torch.zeros(0), torch.zeros(0, 4, 4)
    )
    assert "estimate_after_kidnap" not in plain and not (tmp_path / "p" / "estimate_after_kidnap.txt").exists()
