"""Image quality metrics: PSNR and SSIM (Wang et al. 2004, 11×11 Gaussian window, σ = 1.5)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def psnr_from_mse(mse: float) -> float:
    """Peak signal-to-noise ratio in dB for images in [0, 1]."""
    return -10.0 * math.log10(max(mse, 1e-12))


def psnr(image: torch.Tensor, reference: torch.Tensor) -> float:
    """PSNR (dB) of two (..., 3) images in [0, 1]."""
    return psnr_from_mse(float(((image.double() - reference.double()) ** 2).mean()))


def ssim(image: torch.Tensor, reference: torch.Tensor) -> float:
    """Mean structural similarity of two (H, W, 3) images in [0, 1] (per channel, then averaged)."""
    coords = torch.arange(11, dtype=torch.float64) - 5.0
    gauss = torch.exp(-(coords**2) / (2 * 1.5**2))
    gauss = gauss / gauss.sum()
    window = (gauss[:, None] * gauss[None, :]).expand(3, 1, 11, 11)
    x = image.double().permute(2, 0, 1)[None]
    y = reference.double().permute(2, 0, 1)[None]

    def blur(z: torch.Tensor) -> torch.Tensor:
        return F.conv2d(z, window, groups=3)

    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    value = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return float(value.mean())
