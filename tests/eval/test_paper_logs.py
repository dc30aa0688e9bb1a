"""Reading the original Loc-NeRF's logs and scoring them."""

from __future__ import annotations

import numpy as np
import pytest

from locnerf.eval.paper_logs import read_logged_trials
from locnerf.geometry import rotation_error_deg, translation_error


def test_inerf_compare_logs_read_and_score(shared_data):
    trials = read_logged_trials(shared_data / "locnerf_logs" / "inerf_compare", scene="fern")
    assert [t.frame for t in trials] == [7, 10, 12, 13, 18]
    for trial in trials:
        assert trial.locnerf is not None and trial.inerf is not None and trial.locnerf_no_annealing is not None
        # 301 slots logged, the last one never filled (all zeros): 300 estimates, 2048 rays x 128 samples each.
        assert trial.inerf.poses.shape == (300, 4, 4)
        assert trial.inerf.forward_passes.tolist() == [k * 2048 * 128 for k in range(300)]
        assert trial.locnerf.forward_passes.shape[0] == trial.locnerf.poses.shape[0]
        t_err, r_err = trial.locnerf.errors(trial.truth)
        # The logged Loc-NeRF runs end within a few centimetres on these five frames.
        assert t_err[-1] < 0.05 and r_err[-1] < 5.0


def test_start_pose_follows_the_documented_composition(shared_data):
    trial = read_logged_trials(shared_data / "locnerf_logs" / "inerf_compare", scene="fern")[0]
    start = trial.start_pose()
    # The perturbation is a rotation of at most 40° about some axis (gtsam ypr of it logged).
    assert rotation_error_deg(start, trial.truth) <= 40.0 + 1e-6
    a, b, c = trial.perturbation[:3].tolist()
    rotation = start[:3, :3] @ trial.truth[:3, :3].T
    assert rotation[1, 0].item() == pytest.approx(np.sin(a) * np.cos(b), abs=1e-6)  # the logged truth is float32
    assert translation_error(start, trial.truth) > 0


def test_missing_or_corrupt_logs_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="no logged trials"):
        read_logged_trials(tmp_path)
    np.save(tmp_path / "gt_fern_1_poses.npy", np.eye(3))
    with pytest.raises(ValueError, match="expected shape"):
        read_logged_trials(tmp_path)
    np.save(tmp_path / "gt_fern_1_poses.npy", np.eye(4))
    with pytest.raises(FileNotFoundError, match="start of logged trial fern_1"):
        read_logged_trials(tmp_path)
    with pytest.raises(FileNotFoundError, match="not found"):
        read_logged_trials(tmp_path / "absent")


def _write_trial(folder, inerf_poses: np.ndarray) -> None:
    np.save(folder / "gt_fern_1_poses.npy", np.eye(4))
    np.save(folder / "initial_pose_fern_1_poses.npy", np.zeros(6))
    np.save(folder / "inerf_fern_1_poses.npy", inerf_poses)


def test_unfilled_trailing_slots_are_dropped_and_a_gap_is_refused(tmp_path):
    poses = np.stack([np.eye(4)] * 4)
    poses[1, 0, 3] = 0.5
    poses[3] = 0.0
    _write_trial(tmp_path, poses)
    run = read_logged_trials(tmp_path)[0].inerf
    assert run.poses.shape == (3, 4, 4) and float(run.poses[1, 0, 3]) == 0.5
    assert run.forward_passes.tolist() == [0, 2048 * 128, 2 * 2048 * 128]
    poses[1] = 0.0
    _write_trial(tmp_path, poses)
    with pytest.raises(ValueError, match="slot 1 of 4 is an all-zero matrix"):
        read_logged_trials(tmp_path)


def test_forward_passes_of_another_length_are_refused(tmp_path):
    _write_trial(tmp_path, np.stack([np.eye(4)] * 3))
    np.save(tmp_path / "mocnerf_fern_1_poses.npy", np.stack([np.eye(4)] * 3))
    np.save(tmp_path / "mocnerf_fern_1_forward_passes.npy", np.arange(2))
    with pytest.raises(ValueError, match=r"expected shape \(3,\) to match mocnerf_fern_1_poses.npy"):
        read_logged_trials(tmp_path)
