"""The filter loop's states: whether the particles, the estimate and the odometry agree.

A pose leaves at the odometry rate, carried from the last estimate (no pass over the particles);
the particles' own prediction by the same increment is deferred until the pose is out, and a merge
leaves the estimate to be recomputed by a separate pass. :class:`LoopStateMachine` records which of
those is owed. Every transition starts from settled particles: the one place a deferred prediction
runs is :meth:`LoopStateMachine.settled`, which every transition (and every reader of the
particles) goes through, so no handler can use particles that lag the published odometry.

Transitions (``restart`` from any state):

    WAITING ──restart──> SETTLED ──carry──> PREDICTION_PENDING ──settled──> SETTLED
    SETTLED ──merge (merged)──> ESTIMATE_STALE ──refresh_estimate──> SETTLED
    ESTIMATE_STALE ──carry (refreshes first)──> PREDICTION_PENDING
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from functools import partial

import torch

from locnerf.filter.estimate import ParticleEstimate, carry_estimate
from locnerf.filter.final_search import FinalSearchResult
from locnerf.filter.localizer import Localizer, MergeOutcome, MergeReport
from locnerf_services.filter_loop.dispatcher import CompletedUpdate


class LoopState(enum.Enum):
    """Where the filter loop stands between two pieces of work."""

    WAITING = enum.auto()
    """No particles: waiting for an initial pose or a global-localization command."""
    SETTLED = enum.auto()
    """The particles are predicted to the newest odometry and the estimate is theirs (carried since)."""
    PREDICTION_PENDING = enum.auto()
    """The newest odometry's pose is out; the particles have yet to be predicted by its increment."""
    ESTIMATE_STALE = enum.auto()
    """A merge re-weighed and resampled the particles; the estimate has yet to be recomputed from them."""


class LoopStateMachine:
    """The localizer's particles, the estimate published from them and the prediction owed to them.

    Args:
        localizer: the particle filter (its particles are changed only through this machine).
    """

    def __init__(self, localizer: Localizer) -> None:
        self._localizer = localizer
        self.state = LoopState.WAITING
        self.estimate: ParticleEstimate | None = None
        self._pending_increment: torch.Tensor | None = None
        self._pending_periods = 1.0

    @property
    def running(self) -> bool:
        """Whether the filter has particles."""
        return self.state is not LoopState.WAITING

    def settled(self) -> Localizer:
        """The localizer with every published odometry applied to its particles: a pending prediction
        (eq. 4 on every particle) runs now (PREDICTION_PENDING -> SETTLED)."""
        if self.state is LoopState.PREDICTION_PENDING:
            self._localizer.predict(self._pending_increment, self._pending_periods)
            self._pending_increment = None
            self.state = LoopState.SETTLED
        return self._localizer

    def refresh_estimate(self) -> bool:
        """Recompute the estimate from the particles if a merge changed them (ESTIMATE_STALE -> SETTLED); whether it did."""
        if self.state is not LoopState.ESTIMATE_STALE:
            return False
        self.estimate = self._localizer.estimate()
        self.state = LoopState.SETTLED
        return True

    def restart(self, initialize: Callable[[Localizer], None]) -> None:
        """Draw new particles with ``initialize(localizer)`` (one of its ``initialize_*`` methods) -> SETTLED."""
        localizer = self.settled()
        initialize(localizer)
        self.estimate = localizer.estimate()
        self.state = LoopState.SETTLED

    def carry(self, increment: torch.Tensor | None, periods: float = 1.0) -> ParticleEstimate:
        """The estimate carried by an odometry increment ``T_prev_curr`` (4, 4) in map units (None:
        noise only) spanning ``periods`` odometry periods (> 1 across a gap: wider noise), for the
        pose of that odometry; the particles' prediction by it is deferred (-> PREDICTION_PENDING).

        Raises:
            RuntimeError: in state WAITING (no particles, no estimate to carry).
        """
        if self.state is LoopState.WAITING:
            raise RuntimeError("cannot carry the estimate: the filter has no particles yet (state WAITING)")
        localizer = self.settled()
        self.refresh_estimate()
        self.estimate = carry_estimate(self.estimate, increment, localizer.noise_sigma(periods), localizer.noise_pivot(periods))
        self._pending_increment = increment
        self._pending_periods = periods
        self.state = LoopState.PREDICTION_PENDING
        return self.estimate

    def merge(self, completed: CompletedUpdate) -> MergeReport:
        """Merge a completed update into the particles, then move them by its search's find when it carried one
        (:meth:`Localizer.move_by_search`) (-> ESTIMATE_STALE when merged)."""
        localizer = self.settled()
        find_candidates = None
        if completed.image is not None:
            find_candidates = partial(localizer.keyframe_candidates, completed.image, completed.intrinsics)
        report = localizer.merge(completed.epoch, completed.generation, completed.ids, completed.log_likelihoods, find_candidates, completed.warped)
        if report.outcome is MergeOutcome.MERGED:
            if completed.search is not None and completed.found is not None:
                found = FinalSearchResult(
                    torch.tensor(completed.found.pose, dtype=torch.float64), completed.found.log_likelihood, completed.found.start_log_likelihood, 0
                )
                localizer.move_by_search(completed.search, found)
            self.state = LoopState.ESTIMATE_STALE
        return report
