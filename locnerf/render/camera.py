"""Pinhole camera intrinsics, and the one pixel convention of the library.

Pixel coordinates follow OpenCV (and ROS ``CameraInfo``): the centre of the pixel in column ``u``
and row ``v`` is at ``(u, v)``, so an image of width W covers ``[-0.5, W - 0.5]`` and a camera whose
optical axis meets the image centre has ``cx = (W - 1) / 2``. ``(cx, cy)`` is the principal point in
those coordinates; rays (:mod:`locnerf.render.rays`) go through integer pixel coordinates.

Readers convert at the boundary: the corner convention (the top-left pixel's centre at
``(0.5, 0.5)``: nerfstudio's and instant-ngp's ``transforms.json``, COLMAP, so LLFF) gives
``cx_here = cx_there - 0.5``. Resizing an image keeps its extent, so its pixel edges, not its pixel
centres, scale: :meth:`PinholeIntrinsics.scaled` gives ``cx' = (cx + 0.5)·f - 0.5``; taking every
s-th pixel keeps pixel 0's centre: :meth:`PinholeIntrinsics.decimated` gives ``cx' = cx / s``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import BaseModel, ConfigDict, Field, model_validator

if TYPE_CHECKING:
    import torch


class PinholeIntrinsics(BaseModel):
    """Intrinsics of an undistorted pinhole camera, in pixels, pixel centres at integer coordinates
    (the module's convention: the top-left pixel's centre is ``(0, 0)``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    fx: float = Field(gt=0, description="Focal length along image columns, pixels.")
    fy: float = Field(gt=0, description="Focal length along image rows, pixels.")
    cx: float = Field(description="Principal point column, pixels; the centre of column u is at u (OpenCV's convention).")
    cy: float = Field(description="Principal point row, pixels; the centre of row v is at v (OpenCV's convention).")
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
    def centred(cls, fx: float, fy: float, width: int, height: int) -> PinholeIntrinsics:
        """The camera whose principal point is the image centre, ``((W - 1)/2, (H - 1)/2)``."""
        return cls(fx=fx, fy=fy, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_rad: float) -> PinholeIntrinsics:
        """Square pixels, a centred principal point (:meth:`centred`), focal from the horizontal field
        of view across the image's full width (from its left edge to its right edge)."""
        import math

        focal = 0.5 * width / math.tan(0.5 * horizontal_fov_rad)
        return cls.centred(focal, focal, width, height)

    def scaled(self, factor: float) -> PinholeIntrinsics:
        """Intrinsics of the image resized by ``factor`` (e.g. 0.25 for a 4× downscale) to
        ``round(W·factor) × round(H·factor)`` pixels, as an area or bilinear resize does (cv2.resize,
        torch's ``interpolate``): the image's extent maps onto the new extent, so along each axis, with
        ``f`` the ratio of the new size to the old, ``fx' = fx·f`` and ``cx' = (cx + 0.5)·f - 0.5``.
        """
        width, height = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        fu, fv = width / self.width, height / self.height
        return PinholeIntrinsics(fx=self.fx * fu, fy=self.fy * fv, cx=(self.cx + 0.5) * fu - 0.5, cy=(self.cy + 0.5) * fv - 0.5, width=width, height=height)

    def decimated(self, stride: int) -> PinholeIntrinsics:
        """Intrinsics of ``image[::stride, ::stride]``: new pixel j is old pixel ``j·stride``, so
        ``fx' = fx/stride`` and ``cx' = cx/stride``; the size is ``ceil(W/stride) × ceil(H/stride)``."""
        if stride < 1:
            raise ValueError(f"stride={stride}: expected an integer >= 1")
        return PinholeIntrinsics(
            fx=self.fx / stride,
            fy=self.fy / stride,
            cx=self.cx / stride,
            cy=self.cy / stride,
            width=-(-self.width // stride),
            height=-(-self.height // stride),
        )

    def matrix(self, dtype: torch.dtype | None = None) -> torch.Tensor:
        """The 3×3 calibration matrix K, float64 unless ``dtype`` says otherwise.

        torch is imported here, not with the module: the wire schemas hold intrinsics in processes that never render."""
        import torch

        return torch.tensor([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=dtype or torch.float64)
