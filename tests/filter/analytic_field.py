"""A smooth analytic ray-colour function for filter tests (no map needed).

Each ray is coloured by the point it reaches at unit depth along the optical direction, through
smooth sinusoids: nearby poses give similar colours, distant ones differ.
"""

from __future__ import annotations

import torch


def analytic_render_rays(origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """origins (R, 3), directions (R, 3) -> rgb (R, 3) in [0, 1]."""
    point = origins + 2.0 * directions / directions.norm(dim=-1, keepdim=True)
    frequencies = torch.tensor([[1.3, 0.7, 2.1], [0.9, 1.7, 0.5], [2.3, 1.1, 1.4]], dtype=origins.dtype, device=origins.device)
    return 0.5 + 0.5 * torch.sin(point @ frequencies.T + torch.tensor([0.0, 1.0, 2.0], dtype=origins.dtype))
