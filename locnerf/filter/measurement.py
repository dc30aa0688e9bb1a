"""Measurement model (the paper's eq. 5), in log space.

For M pixels p_j of the observed image I (sampled once per update and shared by every particle),
each particle X_i is weighted by ``w_i = (M / Σ_j ||I(p_j) − C(r(p_j, X_i))||²)^γ`` with γ = 4 in
the paper, C the map's rendered colour. We return ``log w_i = γ (log M − log SSE_i)``.
"""

from __future__ import annotations

from typing import Callable

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.rays import rays_from_poses_and_pixels

RenderRays = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

# Floor on the per-particle squared error, so that a perfect render gives a large finite weight.
_MIN_SQUARED_ERROR = 1e-12


class MeasurementConfig(BaseModel):
    """Photometric likelihood of a particle given sampled pixels."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pixels: int = Field(64, ge=1, description="M: pixels sampled from each image and rendered per particle.")
    exponent: float = Field(4.0, gt=0, description="γ: power of the (M / SSE) likelihood (4 in the paper).")
    ray_chunk: int = Field(
        65536, ge=1, description="Rays per render call; bounds memory when particles × pixels is large."
    )


def sample_pixels(height: int, width: int, count: int, generator: torch.Generator) -> torch.Tensor:
    """M distinct integer pixel coordinates drawn uniformly from an image.

    Returns:
        (M, 2) float32 as (u, v) = (column, row).
    """
    if height < 1 or width < 1:
        raise ValueError(f"image size {width}×{height}: expected a non-empty image")
    if count < 1 or count > height * width:
        raise ValueError(f"pixels M={count}: expected 1 <= M <= {height * width} (the image has {width}×{height} pixels)")
    flat = torch.randperm(height * width, generator=generator)[:count]
    return torch.stack(((flat % width).float(), torch.div(flat, width, rounding_mode="floor").float()), dim=-1)


def observed_colours(image: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Colours of integer pixels: image (H, W, 3) in [0, 1], pixels (M, 2) (u, v) -> (M, 3)."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {tuple(image.shape)}")
    u = pixels[:, 0].long()
    v = pixels[:, 1].long()
    return image[v, u]


def log_likelihood_from_errors(squared_error_sum: torch.Tensor, pixel_count: int, exponent: float) -> torch.Tensor:
    """``γ (log M − log SSE)`` for SSE (N,); non-finite SSE (a NaN render) gives −inf."""
    sse = torch.nan_to_num(squared_error_sum.double(), nan=float("inf")).clamp_min(_MIN_SQUARED_ERROR)
    return exponent * (torch.log(torch.tensor(float(pixel_count), dtype=torch.float64)) - torch.log(sse))


def particle_log_likelihoods(
    poses: torch.Tensor,
    pixels: torch.Tensor,
    observed_rgb: torch.Tensor,
    intrinsics: PinholeIntrinsics,
    render_rays: RenderRays,
    exponent: float = 4.0,
    ray_chunk: int = 65536,
) -> torch.Tensor:
    """Log-likelihood of every particle: render the same M pixels from all N poses in one batch.

    Args:
        poses: (N, 4, 4) particle poses in the map frame.
        pixels: (M, 2) pixel coordinates (u, v) of the observed image.
        observed_rgb: (M, 3) observed colours in [0, 1].
        intrinsics: the observing camera.
        render_rays: the map: origins (R, 3), directions (R, 3) -> rgb (R, 3).
        exponent: γ of eq. 5.
        ray_chunk: rays per render call.
    Returns:
        (N,) float64 log-likelihoods.
    """
    count = pixels.shape[0]
    if observed_rgb.shape != (count, 3):
        raise ValueError(f"observed_rgb: expected shape ({count}, 3) to match the pixels, got {tuple(observed_rgb.shape)}")
    origins, directions = rays_from_poses_and_pixels(poses, pixels, intrinsics)
    flat_origins, flat_dirs = origins.reshape(-1, 3), directions.reshape(-1, 3)
    with torch.no_grad():
        rendered = torch.cat(
            [render_rays(flat_origins[i : i + ray_chunk], flat_dirs[i : i + ray_chunk]) for i in range(0, len(flat_origins), ray_chunk)]
        )
    residual = rendered.reshape(poses.shape[0], count, 3) - observed_rgb.to(rendered.device, rendered.dtype)
    return log_likelihood_from_errors((residual * residual).sum(dim=(1, 2)), count, exponent)
