"""Frequency (positional) encoding, NeRF's γ(p), in nerf-pytorch's layout."""

from __future__ import annotations

import torch


def frequency_encoding(x: torch.Tensor, frequencies: int, include_input: bool = True) -> torch.Tensor:
    """``[x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)]`` along the last axis.

    Args:
        x: (..., D).
        frequencies: L, the number of octaves.
    Returns:
        (..., D·(include_input + 2L)).
    """
    parts = [x] if include_input else []
    for level in range(frequencies):
        scaled = x * (2.0**level)
        parts.extend((torch.sin(scaled), torch.cos(scaled)))
    return torch.cat(parts, dim=-1)
