"""The nerf-pytorch compatibility backend: the original NeRF MLP with hierarchical sampling.

Reproduces nerf-pytorch's network and renderer as the original Loc-NeRF used them: frequency
encodings with 10 octaves for points and 4 for view directions, 8 layers of width 256 with the
input concatenated after the fifth, a 128-wide view branch, and 64 stratified (deterministic at
render time) coarse samples followed by 64 importance samples for the fine network. Checkpoints
are nerf-pytorch ``.tar`` files with ``network_fn_state_dict`` and ``network_fine_state_dict``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from locnerf.errors import MapFileError
from locnerf.field.encoding import frequency_encoding
from locnerf.field.map_info import MapInfo
from locnerf.field.map_state import check_state_dict, entry
from locnerf.field.stored_map import StoredMap

NERF_PYTORCH_KIND = "nerf_pytorch"
POINT_FREQUENCIES, VIEW_FREQUENCIES = 10, 4
DEPTH, WIDTH, SKIP_AFTER = 8, 256, 4
COARSE_SAMPLES, FINE_SAMPLES = 64, 64


class NerfMLP(torch.nn.Module):
    """nerf-pytorch's ``NeRF`` module with view directions (same parameter names and shapes)."""

    def __init__(self) -> None:
        super().__init__()
        point_channels = 3 * (1 + 2 * POINT_FREQUENCIES)
        view_channels = 3 * (1 + 2 * VIEW_FREQUENCIES)
        layers = [torch.nn.Linear(point_channels, WIDTH)]
        layers += [torch.nn.Linear(WIDTH + (point_channels if i == SKIP_AFTER else 0), WIDTH) for i in range(DEPTH - 1)]
        self.pts_linears = torch.nn.ModuleList(layers)
        self.views_linears = torch.nn.ModuleList([torch.nn.Linear(WIDTH + view_channels, WIDTH // 2)])
        self.feature_linear = torch.nn.Linear(WIDTH, WIDTH)
        self.alpha_linear = torch.nn.Linear(WIDTH, 1)
        self.rgb_linear = torch.nn.Linear(WIDTH // 2, 3)

    def forward(self, points: torch.Tensor, view_directions: torch.Tensor) -> torch.Tensor:
        """Raw outputs (P, 4) = (rgb logits, density) for points (P, 3) and unit view directions (P, 3)."""
        encoded_points = frequency_encoding(points, POINT_FREQUENCIES)
        hidden = encoded_points
        for index, layer in enumerate(self.pts_linears):
            hidden = torch.relu(layer(hidden))
            if index == SKIP_AFTER:
                hidden = torch.cat((encoded_points, hidden), dim=-1)
        density = self.alpha_linear(hidden)
        hidden = torch.cat((self.feature_linear(hidden), frequency_encoding(view_directions, VIEW_FREQUENCIES)), dim=-1)
        hidden = torch.relu(self.views_linears[0](hidden))
        return torch.cat((self.rgb_linear(hidden), density), dim=-1)


def composite_raw(raw: torch.Tensor, depths: torch.Tensor, direction_norm: torch.Tensor, white_background: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """nerf-pytorch's ``raw2outputs`` without noise.

    Args:
        raw: (R, S, 4), depths: (R, S) sorted sample parameters, direction_norm: (R,) ray direction lengths.
    Returns:
        rgb (R, 3) and weights (R, S).
    """
    gaps = torch.cat((depths[:, 1:] - depths[:, :-1], torch.full_like(depths[:, :1], 1e10)), dim=-1) * direction_norm[:, None]
    alpha = 1.0 - torch.exp(-torch.relu(raw[..., 3]) * gaps)
    survive = torch.cumprod(torch.cat((torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10), dim=-1), dim=-1)[:, :-1]
    weights = alpha * survive
    rgb = (weights[..., None] * torch.sigmoid(raw[..., :3])).sum(dim=1)
    if white_background:
        rgb = rgb + (1.0 - weights.sum(dim=-1, keepdim=True))
    return rgb, weights


def sample_pdf(bins: torch.Tensor, weights: torch.Tensor, count: int) -> torch.Tensor:
    """Deterministic inverse-CDF samples (nerf-pytorch ``sample_pdf`` with ``det=True``).

    Args:
        bins: (R, B + 1) bin edges, weights: (R, B).
    Returns:
        (R, count) sample positions.
    """
    weights = weights + 1e-5
    pdf = weights / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cat((torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)), dim=-1)
    u = torch.linspace(0.0, 1.0, count, device=bins.device, dtype=bins.dtype).expand(bins.shape[0], count).contiguous()
    above = torch.searchsorted(cdf, u, right=True)
    below = (above - 1).clamp_min(0)
    above = above.clamp_max(cdf.shape[-1] - 1)
    cdf_below, cdf_above = cdf.gather(1, below), cdf.gather(1, above)
    bin_below, bin_above = bins.gather(1, below), bins.gather(1, above)
    denominator = torch.where(cdf_above - cdf_below < 1e-5, torch.ones_like(cdf_below), cdf_above - cdf_below)
    return bin_below + (u - cdf_below) / denominator * (bin_above - bin_below)


class NerfPytorchMap(StoredMap):
    """A RadianceMap running nerf-pytorch's coarse and fine MLPs."""

    kind = NERF_PYTORCH_KIND

    def __init__(self, coarse: NerfMLP, fine: NerfMLP, info: MapInfo, white_background: bool, chunk: int = 32768) -> None:
        self.coarse = coarse
        self.fine = fine
        self.info = info
        self.white_background = white_background
        self.chunk = chunk

    @property
    def samples_per_ray(self) -> int:
        return COARSE_SAMPLES + FINE_SAMPLES

    @property
    def device(self) -> torch.device:
        return next(self.coarse.parameters()).device

    def _query(self, network: NerfMLP, origins: torch.Tensor, directions: torch.Tensor, views: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
        points = origins[:, None] + depths[..., None] * directions[:, None]
        flat_views = views[:, None].expand(points.shape).reshape(-1, 3)
        flat_points = points.reshape(-1, 3)
        raw = torch.cat([network(flat_points[i : i + self.chunk], flat_views[i : i + self.chunk]) for i in range(0, len(flat_points), self.chunk)])
        return raw.view(*depths.shape, 4)

    @torch.no_grad()
    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """rgb (R, 3) of world-frame rays (R, 3) x2, with 64 coarse + 64 fine samples per ray (the
        background for rays looking away from an NDC map's scene)."""
        origins = origins.to(self.device, torch.float32)
        directions = directions.to(self.device, torch.float32)
        background = torch.full((3,), 1.0 if self.white_background else 0.0)
        return self.info.render_world_rays(origins, directions, self._render_field_rays, background)

    def _render_field_rays(self, field_origins: torch.Tensor, field_directions: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """rgb (R, 3) of field-space rays (R, 3) x2 seen along world-frame ``directions`` (R, 3)."""
        views = directions / directions.norm(dim=-1, keepdim=True)
        near, far = (0.0, 1.0) if self.info.normalization.ndc else (self.info.normalization.near, self.info.normalization.far)
        steps = torch.linspace(0.0, 1.0, COARSE_SAMPLES, device=self.device)
        depths = (near * (1.0 - steps) + far * steps).expand(len(field_origins), COARSE_SAMPLES)
        norm = field_directions.norm(dim=-1)
        _, weights = composite_raw(self._query(self.coarse, field_origins, field_directions, views, depths), depths, norm, self.white_background)
        middles = 0.5 * (depths[:, 1:] + depths[:, :-1])
        fine_depths = sample_pdf(middles, weights[:, 1:-1], FINE_SAMPLES)
        depths, _ = torch.sort(torch.cat((depths, fine_depths), dim=-1), dim=-1)
        rgb, _ = composite_raw(self._query(self.fine, field_origins, field_directions, views, depths), depths, norm, self.white_background)
        return rgb.clamp(0.0, 1.0)

    def state(self) -> dict[str, Any]:
        """Weights for the map file."""
        return {
            "network_fn_state_dict": {k: v.detach().cpu().clone() for k, v in self.coarse.state_dict().items()},
            "network_fine_state_dict": {k: v.detach().cpu().clone() for k, v in self.fine.state_dict().items()},
            "white_background": self.white_background,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any], info: MapInfo, device: torch.device) -> NerfPytorchMap:
        """Networks from nerf-pytorch state dicts (a map-file state or a checkpoint's dicts).

        Raises:
            MapFileError: when a state dict is missing or its names or shapes differ from nerf-pytorch's
                8x256 network with view directions.
        """
        coarse, fine = NerfMLP(), NerfMLP()
        for network, key in ((coarse, "network_fn_state_dict"), (fine, "network_fine_state_dict")):
            weights = entry(state, key, dict, "nerf-pytorch state")
            check_state_dict(weights, network.state_dict(), f"nerf-pytorch state: {key} (expected nerf-pytorch's 8x256 layout with view directions)")
            network.load_state_dict(weights)
        return cls(coarse.to(device).eval(), fine.to(device).eval(), info, bool(state.get("white_background", False)))


def load_nerf_pytorch_checkpoint(checkpoint: str | Path, info: MapInfo, white_background: bool, device: torch.device | str = "cpu") -> NerfPytorchMap:
    """A map from a nerf-pytorch ``.tar`` checkpoint; ``info`` comes from the data set it was trained on.

    Raises:
        MapFileError: naming the file when it lacks the network state dicts or their shapes differ.
    """
    path = Path(checkpoint)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path}: no such file")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # truncated or not a torch archive
        raise MapFileError(f"checkpoint {path}: cannot be read as a nerf-pytorch checkpoint ({error})") from error
    if not isinstance(content, dict):
        raise MapFileError(f"checkpoint {path}: a {type(content).__name__}, expected a nerf-pytorch .tar dict with both networks")
    try:
        return NerfPytorchMap.from_state({**content, "white_background": white_background}, info, torch.device(device))
    except MapFileError as error:
        raise MapFileError(f"checkpoint {path}: {error}") from None
