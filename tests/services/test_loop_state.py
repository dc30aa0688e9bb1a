"""The filter loop's state machine: every transition starts from particles predicted to the newest odometry."""

from __future__ import annotations

import pytest
import torch

from locnerf.config import preset
from locnerf.filter.localizer import Localizer, MergeOutcome
from locnerf.geometry.se3 import make_pose
from locnerf_services.filter_loop.dispatcher import CompletedUpdate
from locnerf_services.filter_loop.loop_state import LoopState, LoopStateMachine

STEP = make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([0.0, 0.0, -0.1], dtype=torch.float64))


def _machine() -> tuple[LoopStateMachine, Localizer]:
    localizer = Localizer(preset("llff"), torch.Generator().manual_seed(0), dtype=torch.float64)
    return LoopStateMachine(localizer), localizer


def _started() -> tuple[LoopStateMachine, Localizer]:
    machine, localizer = _machine()
    covariance = torch.diag(torch.tensor([1e-4] * 3 + [1e-3] * 3, dtype=torch.float64))
    machine.restart(lambda loc: loc.initialize_gaussian(torch.eye(4, dtype=torch.float64), covariance))
    return machine, localizer


def _completed(localizer: Localizer) -> CompletedUpdate:
    """An update on the current particles that prefers those with a larger x."""
    snapshot = localizer.snapshot()
    return CompletedUpdate(snapshot.epoch, snapshot.generation, snapshot.ids, snapshot.poses[:, 0, 3].double() * 100, 0.1, None, None)


def test_waiting_until_particles_are_drawn_and_no_estimate_to_carry():
    machine, _ = _machine()
    assert machine.state is LoopState.WAITING and not machine.running and machine.estimate is None
    with pytest.raises(RuntimeError, match="WAITING"):
        machine.carry(STEP)


def test_carry_defers_the_prediction_and_settled_applies_it_once():
    machine, localizer = _started()
    assert machine.state is LoopState.SETTLED
    before = localizer.particles.poses.clone()
    carried = machine.carry(STEP)
    assert machine.state is LoopState.PREDICTION_PENDING and torch.equal(localizer.particles.poses, before)
    assert torch.allclose(carried.pose, localizer.estimate().pose @ STEP, atol=1e-12)
    machine.settled()
    moved = localizer.particles.poses.clone()
    assert machine.state is LoopState.SETTLED and not torch.equal(moved, before)
    machine.settled()
    assert torch.equal(localizer.particles.poses, moved), "nothing left to apply"


@pytest.mark.parametrize("transition", ["merge", "restart", "carry"])
def test_every_transition_out_of_a_pending_prediction_predicts_first(transition):
    machine, localizer = _started()
    completed = _completed(localizer)
    calls: list[str] = []
    for name in ("predict", "merge", "initialize"):
        method = getattr(localizer, name)
        setattr(localizer, name, lambda *args, _name=name, _method=method, **kwargs: (calls.append(_name), _method(*args, **kwargs))[1])
    machine.carry(STEP)
    if transition == "merge":
        machine.merge(completed)
    elif transition == "restart":
        machine.restart(lambda loc: loc.initialize(torch.eye(4, dtype=torch.float64)[None]))
    else:
        machine.carry(STEP)
    assert calls[0] == "predict" and calls.count("predict") == 1


def test_a_merge_makes_the_estimate_stale_and_carry_refreshes_it_first():
    machine, localizer = _started()
    report = machine.merge(_completed(localizer))
    assert report.outcome is MergeOutcome.MERGED and machine.state is LoopState.ESTIMATE_STALE
    fresh = localizer.estimate()
    carried = machine.carry(None)
    assert torch.allclose(carried.pose, fresh.pose, atol=1e-12) and machine.state is LoopState.PREDICTION_PENDING
    assert not machine.refresh_estimate()


def test_a_stale_merge_leaves_the_state_alone():
    machine, localizer = _started()
    completed = _completed(localizer)
    machine.restart(lambda loc: loc.initialize(torch.eye(4, dtype=torch.float64)[None].repeat(4, 1, 1)))  # a new epoch
    assert machine.merge(completed).outcome is MergeOutcome.STALE and machine.state is LoopState.SETTLED
