"""Recovery from kidnapping: augmented MCL (Thrun, Burgard & Fox, Probabilistic Robotics, §8.3.5).

Two exponential averages of the mean measurement likelihood are kept, a slow one and a fast one:
``w_slow += α_slow (w_avg − w_slow)``, ``w_fast += α_fast (w_avg − w_fast)``. After each update a
fraction ``max(0, 1 − w_fast / w_slow)`` of the particles is replaced by random ones: when the
recent likelihood falls well below the long-term one, the filter is probably lost. Everything is
kept in log space because eq. 5's likelihoods span hundreds of orders of magnitude. Off by default,
as in amcl.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, model_validator


class RecoveryConfig(BaseModel):
    """Augmented-MCL random-particle injection."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(False, description="Inject random particles when the likelihood collapses.")
    alpha_slow: float = Field(0.05, gt=0, le=1, description="Rate of the long-term likelihood average.")
    alpha_fast: float = Field(0.5, gt=0, le=1, description="Rate of the short-term likelihood average.")
    max_fraction: float = Field(0.5, ge=0, le=1, description="Upper bound on the fraction of particles replaced per update.")

    @model_validator(mode="after")
    def _fast_above_slow(self) -> "RecoveryConfig":
        if self.alpha_fast <= self.alpha_slow:
            raise ValueError(f"alpha_fast={self.alpha_fast} <= alpha_slow={self.alpha_slow}: expected alpha_fast > alpha_slow")
        return self


def _log_ema(log_average: float | None, log_value: float, rate: float) -> float:
    """log((1 − α)·avg + α·value) from logs; the first value initialises the average."""
    if log_average is None:
        return log_value
    a, b = math.log1p(-rate) + log_average if rate < 1 else -math.inf, math.log(rate) + log_value
    high = max(a, b)
    return high + math.log(math.exp(a - high) + math.exp(b - high))


class LikelihoodAverages:
    """The slow and fast log-likelihood averages of augmented MCL."""

    def __init__(self, config: RecoveryConfig) -> None:
        self.config = config
        self.log_slow: float | None = None
        self.log_fast: float | None = None

    def reset(self) -> None:
        """Forget the history (after a re-initialisation)."""
        self.log_slow = self.log_fast = None

    def observe(self, log_mean_likelihood: float) -> float:
        """Feed one update's log mean likelihood; return the fraction of particles to replace."""
        if not math.isfinite(log_mean_likelihood):
            return 0.0
        self.log_slow = _log_ema(self.log_slow, log_mean_likelihood, self.config.alpha_slow)
        self.log_fast = _log_ema(self.log_fast, log_mean_likelihood, self.config.alpha_fast)
        if not self.config.enabled:
            return 0.0
        ratio = math.exp(min(0.0, self.log_fast - self.log_slow))
        return min(self.config.max_fraction, max(0.0, 1.0 - ratio))
