"""Volume rendering pieces shared by the map backends: ray-box clipping and density compositing.

Quadrature (Max 1995; NeRF eq. 3): with densities σ_k and segment lengths δ_k along a ray,
``α_k = 1 - exp(-σ_k δ_k)``, transmittance ``T_k = exp(-Σ_{j<k} σ_j δ_j)`` and weights
``w_k = T_k α_k``; the ray colour is ``Σ w_k c_k + (1 - Σ w_k) · background``.
"""

from __future__ import annotations

import torch


def ray_box_intersection(origins: torch.Tensor, directions: torch.Tensor, box: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit ray parameters of an axis-aligned box (slab method).

    Args:
        origins: (R, 3), directions: (R, 3), box: (2, 3) min and max corner.
    Returns:
        t_entry (R,), t_exit (R,), with ``t_entry >= 0``; rays missing the box have
        ``t_exit <= t_entry``.
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t_low = (box[0] - origins) / safe
    t_high = (box[1] - origins) / safe
    t_entry = torch.minimum(t_low, t_high).amax(dim=-1).clamp_min(0.0)
    t_exit = torch.maximum(t_low, t_high).amin(dim=-1)
    return t_entry, t_exit


def weights_from_optical_depth(optical_depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Compositing weights from per-sample optical depths ``σ_k δ_k``.

    Args:
        optical_depth: (R, S) non-negative σ·δ per sample, in ray order.
    Returns:
        weights: (R, S) ``T_k α_k``; transmittance: (R,) left after the last sample.
    """
    alpha = 1.0 - torch.exp(-optical_depth)
    before = torch.cumsum(optical_depth, dim=-1) - optical_depth
    weights = torch.exp(-before) * alpha
    transmittance = torch.exp(-optical_depth.sum(dim=-1))
    return weights, transmittance
