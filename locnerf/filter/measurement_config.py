"""The measurement model's settings (:mod:`locnerf.filter.measurement`), apart from its torch code: the wire schemas and
the configuration files read them in processes that never render."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator


def _check_gain_range(value: tuple[float, float] | None) -> tuple[float, float] | None:
    if value is not None and not 0 < value[0] <= 1 <= value[1]:
        raise ValueError(f"exposure_gain_range={value}: expected 0 < low <= 1 <= high")
    return value


ExposureGainRange = Annotated[tuple[float, float] | None, AfterValidator(_check_gain_range)]
"""Bounds [low, high] of the exposure-invariant likelihood's fitted gain, 0 < low <= 1 <= high; None: off."""


class WarpConfig(BaseModel):
    """When and how a converged cloud is weighed by re-projection (:mod:`locnerf.filter.warp`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_spread: float = Field(gt=0, description="Warp only while the largest per-axis weighted std of particle positions is at most this (map units).")
    max_rotation_spread_deg: float = Field(5.0, gt=0, description="... and the largest rotation std (degrees) of the cloud is at most this.")
    pixels: int = Field(512, ge=1, description="M: reference pixels re-projected into every particle's view.")
    stride: int = Field(
        2, ge=1, description="The reference view is rendered at every stride-th pixel (in both directions); the M are drawn from that render by its gradient."
    )
    occlusion_margin: float = Field(
        0.05,
        ge=0,
        description="A reference pixel with a neighbour (within occlusion_pixels) closer by more than this fraction of its depth is on the far side of"
        " an edge, where a nearby view sees the occluder instead: it is not drawn.",
    )
    occlusion_pixels: int = Field(
        4, ge=0, description="Neighbourhood of that test, image pixels (the parallax a converged cloud's spread can cause between near and far surfaces)."
    )
    min_opacity: float = Field(
        0.5, ge=0, le=1, description="A pixel whose ray is less opaque than this is a direction at infinity (background), not a surface point."
    )


class DepthConfig(BaseModel):
    """The depth term of the likelihood for RGB-D cameras (:mod:`locnerf.filter.depth_measurement`); ``[measurement.depth]`` turns it on.

    It lives here, beside :class:`WarpConfig`, so that :class:`MeasurementConfig` can hold it without an import cycle."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pixels: int = Field(256, ge=1, description="M_d: depth pixels per update, drawn uniformly among the valid readings.")
    truncation: float = Field(
        0.1, gt=0, description="c, map units: a depth residual counts at most this much (robust to holes, depth edges and moving things)."
    )
    exponent: float = Field(4.0, gt=0, description="γ_d: power of the (M / Σ min(r², c²)) depth likelihood.")
    likelihood: Literal["rendered", "surface_distance"] = Field(
        "rendered",
        description="rendered: r is the map's rendered depth minus the reading, along each particle's depth rays (or re-projected once converged);"
        " surface_distance: r is the distance from the reading's point, placed by each particle's pose, to the nearest surface of the map's"
        " surface-distance layer (maps built from depth images), a lookup instead of a render.",
    )
    min_depth: float = Field(0.1, ge=0, description="Readings nearer than this (map units) are invalid.")
    max_depth: float = Field(6.0, gt=0, description="Readings farther than this (map units) are invalid.")

    @model_validator(mode="after")
    def _ordered(self) -> DepthConfig:
        if self.min_depth >= self.max_depth:
            raise ValueError(f"min_depth={self.min_depth}, max_depth={self.max_depth}: expected min_depth < max_depth")
        return self


class MeasurementConfig(BaseModel):
    """Photometric likelihood of a particle given sampled pixels."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pixels: int = Field(64, ge=1, description="M: pixels sampled from each image and rendered per particle.")
    exponent: float = Field(4.0, gt=0, description="γ: power of the (M / SSE) likelihood (4 in the paper).")
    sampling: Literal["uniform", "gradient"] = Field(
        "gradient", description="How the M pixels are drawn: uniform (the original) or weighted by image gradient (module docstring)."
    )
    gradient_share: float = Field(0.75, ge=0, le=1, description="gradient sampling: fraction of the M pixels drawn by gradient weight.")
    ray_chunk: int = Field(65536, ge=1, description="Rays per render call; bounds memory when particles × pixels is large.")
    ray_budget: int | None = Field(
        None,
        ge=1,
        description="Most rays (particles × pixels) an update renders: with N particles it looks at min(pixels, ray_budget // N) "
        "pixels, at least min_pixels (None: always `pixels`). A spread (global) cloud of many particles then takes many cheap "
        "updates, and the full `pixels` come back as KLD-sampling shrinks the cloud.",
    )
    min_pixels: int = Field(16, ge=1, description="ray_budget: fewest pixels an update looks at, however many particles.")

    exposure_gain_range: ExposureGainRange = Field(
        None,
        description="Exposure-invariant likelihood (module docstring): the per-particle, per-channel gain fitted to the"
        " observed pixels is clamped to [low, high] (e.g. (0.5, 2.0)); None compares renders as they are (the original)."
        " The in-process localizer applies it, and the live filter sends it to the workers with each update request.",
    )

    warp: WarpConfig | None = Field(
        None,
        description="Weigh a converged cloud by re-projecting one reference render into every particle's view (locnerf.filter.warp)"
        " instead of rendering from every particle; None: always render (the original).",
    )

    depth: DepthConfig | None = Field(
        None,
        description="Depth term for RGB-D cameras (locnerf.filter.depth_measurement): added to the colour log-likelihood of frames"
        " that come with a depth image; None: colour only (the original).",
    )

    def pixels_for(self, particles: int) -> int:
        """M for an update of ``particles`` particles under the ray budget (see ``ray_budget``)."""
        if particles < 1:
            raise ValueError(f"particles={particles}: expected at least 1 particle to weigh")
        if self.ray_budget is None:
            return self.pixels
        return min(self.pixels, max(self.min_pixels, self.ray_budget // particles))
