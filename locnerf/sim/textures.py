"""View-independent procedural textures: colour as a function of a surface point and its surface id.

A texture mixes three scales so that the photometric likelihood has both a wide basin and a sharp
optimum: a per-surface base colour, smooth colour waves with metre-scale wavelengths, and
high-frequency detail (value noise at a few centimetres to decimetres plus stripes).
"""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

_HASH_PRIMES = (73856093, 19349663, 83492791)
_NOISE_TABLE_SIZE = 1 << 16


class TextureConfig(BaseModel):
    """Scales and strengths of the procedural texture."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    base_weight: float = Field(0.45, ge=0, description="Weight of the per-surface base colour.")
    wave_weight: float = Field(0.35, ge=0, description="Weight of the smooth colour waves.")
    detail_weight: float = Field(0.25, ge=0, description="Weight of the high-frequency detail.")
    wave_count: int = Field(4, ge=1, description="Smooth colour waves summed per channel.")
    wave_min_wavelength: float = Field(1.0, gt=0, description="Shortest wavelength of the smooth waves, metres.")
    wave_max_wavelength: float = Field(4.0, gt=0, description="Longest wavelength of the smooth waves, metres.")
    noise_cell: float = Field(0.12, gt=0, description="Lattice spacing of the detail value noise, metres.")
    stripe_period: float = Field(0.3, gt=0, description="Period of the detail stripes, metres.")


class ProceduralTexture:
    """Random texture parameters drawn once from a generator; evaluation is deterministic.

    Args:
        surface_count: number of distinct surfaces (each gets a base colour and a stripe direction).
        config: texture scales.
        generator: CPU generator for the parameters.
    """

    def __init__(self, surface_count: int, config: TextureConfig, generator: torch.Generator) -> None:
        self.config = config
        self.base_colours = 0.15 + 0.7 * torch.rand(surface_count, 3, dtype=torch.float64, generator=generator)
        directions = torch.randn(config.wave_count, 3, 3, dtype=torch.float64, generator=generator)
        directions = directions / directions.norm(dim=-1, keepdim=True)
        wavelengths = config.wave_min_wavelength + (config.wave_max_wavelength - config.wave_min_wavelength) * torch.rand(
            config.wave_count, 3, 1, dtype=torch.float64, generator=generator
        )
        self.wave_vectors = directions * (2 * torch.pi / wavelengths)  # (K, 3 channels, 3 coords)
        self.wave_phases = 2 * torch.pi * torch.rand(config.wave_count, 3, dtype=torch.float64, generator=generator)
        stripes = torch.randn(surface_count, 3, dtype=torch.float64, generator=generator)
        self.stripe_vectors = stripes / stripes.norm(dim=-1, keepdim=True) * (2 * torch.pi / config.stripe_period)
        self.noise_table = torch.rand(_NOISE_TABLE_SIZE, 3, dtype=torch.float64, generator=generator)

    def _value_noise(self, points: torch.Tensor) -> torch.Tensor:
        """Trilinearly interpolated lattice noise: points (R, 3) -> (R, 3) in [0, 1]."""
        scaled = points / self.config.noise_cell
        cell = torch.floor(scaled)
        frac = scaled - cell
        smooth = frac * frac * (3 - 2 * frac)  # smoothstep keeps the noise C¹
        corner_base = cell.to(torch.int64)
        primes = torch.tensor(_HASH_PRIMES, dtype=torch.int64, device=points.device)
        table = self.noise_table.to(points.device, points.dtype)
        result = torch.zeros(points.shape[0], 3, dtype=points.dtype, device=points.device)
        for corner in range(8):
            offset = torch.tensor([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], dtype=torch.int64, device=points.device)
            lattice = corner_base + offset
            key = (lattice[:, 0] * primes[0]) ^ (lattice[:, 1] * primes[1]) ^ (lattice[:, 2] * primes[2])
            values = table[torch.remainder(key, _NOISE_TABLE_SIZE)]
            weight = torch.where(offset.bool(), smooth, 1 - smooth).prod(dim=-1, keepdim=True)
            result = result + weight * values
        return result

    def colour(self, points: torch.Tensor, surface_ids: torch.Tensor) -> torch.Tensor:
        """Texture colour of surface points.

        Args:
            points: (R, 3) hit points, metres.
            surface_ids: (R,) int64 surface index of each point.
        Returns:
            (R, 3) rgb in [0, 1].
        """
        dtype, device = points.dtype, points.device
        config = self.config
        base = self.base_colours.to(device, dtype)[surface_ids]
        waves = torch.einsum("kcd,rd->rkc", self.wave_vectors.to(device, dtype), points) + self.wave_phases.to(device, dtype)
        wave = 0.5 + 0.5 * torch.sin(waves).mean(dim=1)
        stripe = 0.5 + 0.5 * torch.sin((points * self.stripe_vectors.to(device, dtype)[surface_ids]).sum(dim=-1, keepdim=True))
        detail = 0.6 * self._value_noise(points) + 0.4 * stripe
        total = config.base_weight + config.wave_weight + config.detail_weight
        rgb = (config.base_weight * base + config.wave_weight * wave + config.detail_weight * detail) / total
        return rgb.clamp(0.0, 1.0)
