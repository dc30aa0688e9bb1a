"""The cross-entropy search's settings (:mod:`locnerf.filter.final_search`), apart from its torch code: the wire schemas carry
them in processes that never render."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

MAX_ITERATIONS = 50
"""Most cross-entropy rounds a search may ask for (a search travels in update requests: a worker is not held for hours)."""

MAX_CANDIDATES = 4096
"""Most poses per round a search may ask for."""

MAX_PIXELS = 16384
"""Most colour pixels a search may draw for itself (a search travels in update requests)."""


class CrossEntropyConfig(BaseModel):
    """The cross-entropy search's budget and spreads (module docstring), on whatever likelihood it is given."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    iterations: int = Field(6, ge=1, le=MAX_ITERATIONS, description="Cross-entropy rounds.")
    candidates: int = Field(64, ge=2, le=MAX_CANDIDATES, description="Poses rendered per round (the current mean among them).")
    elite: int = Field(8, ge=2, description="Best candidates that give the next round's mean and covariance.")
    inflation: float = Field(2.0, gt=0, description="The first round's covariance is the cloud's times inflation².")
    min_position: float = Field(0.002, ge=0, description="Floor of the search's position standard deviation per axis (map units).")
    min_rotation_deg: float = Field(0.1, ge=0, description="Floor of the search's rotation standard deviation per axis (degrees).")
    start_position: float = Field(
        0.0, ge=0, description="Added to the first round only: position standard deviation per axis (map units), however narrow the cloud is."
    )
    start_rotation_deg: float = Field(0.0, ge=0, description="Added to the first round only: rotation standard deviation per axis (degrees).")
    pivot_depth: float | None = Field(
        None, gt=0, description="Widen the first round along the valley: swings about the point this far ahead of the camera (map units; None: off)."
    )
    pivot_sigma_deg: float = Field(1.0, ge=0, description="Standard deviation of those swings about the camera's x and y axes (degrees).")
    pixels: int | None = Field(
        None,
        ge=1,
        le=MAX_PIXELS,
        description="Colour pixels the search draws from the image for itself (by the measurement's sampling rule) and renders from every "
        "candidate in place of the update's colour pixels, the update's depth term kept; None: the update's own likelihood.",
    )

    @model_validator(mode="after")
    def _elite_within_candidates(self) -> CrossEntropyConfig:
        if self.elite > self.candidates:
            raise ValueError(f"elite={self.elite} > candidates={self.candidates}: expected at most as many elite as candidates")
        return self
