"""Pinhole camera intrinsics.

Pixel coordinates follow OpenCV: the centre of the pixel in column ``u`` and row ``v`` is at
``(u, v)``, and ``(cx, cy)`` is the principal point in those coordinates. (nerf-pytorch's rays use
``cx = W/2, cy = H/2`` in this same convention; the dataset readers reproduce that choice.)
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator


class PinholeIntrinsics(BaseModel):
    """Intrinsics of an undistorted pinhole camera, in pixels."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    fx: float = Field(gt=0, description="Focal length along image columns, pixels.")
    fy: float = Field(gt=0, description="Focal length along image rows, pixels.")
    cx: float = Field(description="Principal point column, pixels (OpenCV pixel-centre convention).")
    cy: float = Field(description="Principal point row, pixels (OpenCV pixel-centre convention).")
    width: int = Field(gt=0, description="Image width, pixels.")
    height: int = Field(gt=0, description="Image height, pixels.")

    @model_validator(mode="after")
    def _finite(self) -> PinholeIntrinsics:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if value != value or value in (float("inf"), float("-inf")):
                raise ValueError(f"{name}={value}: expected a finite number")
        return self

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_rad: float) -> PinholeIntrinsics:
        """Square pixels, principal point at ``(W/2, H/2)``, focal from the horizontal field of view."""
        import math

        focal = 0.5 * width / math.tan(0.5 * horizontal_fov_rad)
        return cls(fx=focal, fy=focal, cx=width / 2.0, cy=height / 2.0, width=width, height=height)

    def scaled(self, factor: float) -> PinholeIntrinsics:
        """Intrinsics of the image resized by ``factor`` (e.g. 0.25 for a 4× downscale)."""
        return PinholeIntrinsics(
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=self.cx * factor,
            cy=self.cy * factor,
            width=max(1, round(self.width * factor)),
            height=max(1, round(self.height * factor)),
        )

    def matrix(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """The 3×3 calibration matrix K."""
        return torch.tensor([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=dtype)
