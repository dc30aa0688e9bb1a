"""The grid radiance field: a dense voxel grid of density, diffuse colour and view features.

Design (chosen by measurement on a 2-core CPU, see docs/MAPS.md): one dense grid of
``1 + 3 + F`` channels, stored vertex-major as a (V, C) table and interpolated trilinearly as a
weighted ``embedding_bag`` of the 8 corner vertices (its backward pass is a plain scatter-add, about
twice as fast on CPU as ``grid_sample``'s 3-D backward): density (softplus with a shift so
that the initial opacity is tiny, as in DVGO), diffuse colour (sigmoid) and F view features. The
view-dependent part is deferred: the composited features of a ray and its direction go through a
tiny MLP once per ray (as in SNeRG), so the per-sample cost is one trilinear lookup. An occupancy
grid (dilated) skips empty space; rays march in blocks and stop once their transmittance is spent.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from locnerf.field.encoding import frequency_encoding
from locnerf.render.volume import ray_box_intersection, weights_from_optical_depth


class GridFieldConfig(BaseModel):
    """Shape of a grid field."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    voxels: int = Field(128**3, gt=0, description="Target number of grid vertices (split over the axes by the box's aspect).")
    features: int = Field(8, ge=0, description="View-feature channels per vertex, decoded per ray by the MLP.")
    decoder_width: int = Field(64, gt=0, description="Hidden width of the per-ray view-dependent decoder.")
    direction_frequencies: int = Field(2, ge=0, description="Octaves of the frequency encoding of the view direction.")
    step_ratio: float = Field(0.5, gt=0, description="Sample spacing along rays, in voxels.")
    initial_alpha: float = Field(1e-4, gt=0, lt=1, description="Opacity of one step at initialisation (sets the density shift).")
    occupancy_alpha: float = Field(1e-3, gt=0, lt=1, description="A voxel is occupied when one step through it is at least this opaque.")
    termination_transmittance: float = Field(1e-3, gt=0, lt=1, description="Rays stop marching below this transmittance.")
    block_samples: int = Field(48, gt=0, description="Samples per marching block when rendering without gradients.")
    coarse_factor: int = Field(8, ge=2, description="Voxels per cell edge of the coarse occupancy grid that clips rays before marching.")


def grid_shape_for_box(box: torch.Tensor, voxels: int) -> tuple[int, int, int]:
    """(Rx, Ry, Rz) vertices per axis with cubic voxels and about ``voxels`` vertices in all."""
    extent = (box[1] - box[0]).double()
    size = (float(extent.prod()) / voxels) ** (1.0 / 3.0)
    return tuple(max(2, int(math.ceil(float(e) / size)) + 1) for e in extent)  # type: ignore[return-value]


class GridField(torch.nn.Module):
    """Dense-grid field over an axis-aligned box, with its own ray marcher.

    Points and rays are in the field's space (the map frame, or NDC for forward-facing maps).
    """

    def __init__(self, box: torch.Tensor, config: GridFieldConfig, background: tuple[float, float, float] | None) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("box", box.float().clone())
        self.register_buffer("background", torch.tensor(background if background is not None else (0.0, 0.0, 0.0)))
        self.has_background = background is not None
        rx, ry, rz = grid_shape_for_box(box, config.voxels)
        channels = 4 + config.features
        self._resolution = (rx, ry, rz)
        self.grid = torch.nn.Parameter(torch.zeros(rx * ry * rz, channels))
        self.register_buffer("occupancy", torch.ones(rz, ry, rx, dtype=torch.bool))
        self.register_buffer("occupied_box", box.float().clone())
        in_features = config.features + 3 * (1 + 2 * config.direction_frequencies)
        self.decoder = torch.nn.Sequential(
            torch.nn.Linear(in_features, config.decoder_width),
            torch.nn.ReLU(),
            torch.nn.Linear(config.decoder_width, 3),
        )
        torch.nn.init.zeros_(self.decoder[2].weight)
        torch.nn.init.zeros_(self.decoder[2].bias)

    @property
    def resolution(self) -> tuple[int, int, int]:
        """(Rx, Ry, Rz) vertices per axis."""
        return self._resolution

    @property
    def voxel_size(self) -> float:
        """Edge of one voxel in field units."""
        return float((self.box[1, 0] - self.box[0, 0]) / (self.resolution[0] - 1))

    @property
    def density_shift(self) -> float:
        """Added to raw density before softplus so that a zero grid has opacity ``initial_alpha`` per step."""
        alpha = self.config.initial_alpha
        return math.log(math.expm1(-math.log(1.0 - alpha) / self.config.step_ratio))

    def resize(self, resolution: tuple[int, int, int]) -> None:
        """Trilinearly resample the grid to (Rx, Ry, Rz) vertices (coarse-to-fine training)."""
        rx, ry, rz = resolution
        old_x, old_y, old_z = self._resolution
        channels = self.grid.shape[1]
        with torch.no_grad():
            volume = self.grid.data.t().reshape(1, channels, old_z, old_y, old_x)
            resized = F.interpolate(volume, size=(rz, ry, rx), mode="trilinear", align_corners=True)
        self._resolution = (rx, ry, rz)
        self.grid = torch.nn.Parameter(resized.reshape(channels, -1).t().contiguous())
        self.occupancy = F.interpolate(self.occupancy[None, None].float(), size=(rz, ry, rx), mode="nearest")[0, 0] > 0

    def sample_grid(self, points: torch.Tensor) -> torch.Tensor:
        """Trilinear grid values: points (P, 3) -> (P, 4 + F) raw channels (clamped to the box)."""
        rx, ry, rz = self._resolution
        cells = torch.tensor([rx - 1, ry - 1, rz - 1], device=points.device, dtype=points.dtype)
        position = ((points - self.box[0]) / (self.box[1] - self.box[0]) * cells).clamp_min(0.0)
        position = torch.minimum(position, cells)
        corner = torch.minimum(position.floor(), cells - 1)
        fraction = position - corner
        corner = corner.long()
        base = (corner[:, 2] * ry + corner[:, 1]) * rx + corner[:, 0]
        offsets = torch.tensor([(dz * ry + dy) * rx + dx for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], device=points.device)
        bits = torch.tensor([[dx, dy, dz] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], device=points.device, dtype=points.dtype)
        # weight of corner (dx, dy, dz) = Π_axis (f if bit else 1 - f)
        weights = (bits * fraction[:, None] + (1 - bits) * (1 - fraction[:, None])).prod(dim=-1)
        return F.embedding_bag(base[:, None] + offsets, self.grid, per_sample_weights=weights, mode="sum")

    def optical_depth(self, raw_density: torch.Tensor) -> torch.Tensor:
        """σ·δ for one step (δ = ``step_ratio`` voxels): softplus(raw + shift) · step_ratio."""
        return F.softplus(raw_density + self.density_shift) * self.config.step_ratio

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """(P,) bool: the nearest vertex of each point (P, 3) is marked occupied (and it lies in the box)."""
        rx, ry, rz = self.resolution
        cells = torch.tensor([rx - 1, ry - 1, rz - 1], device=points.device, dtype=points.dtype)
        # Vertex coordinates shifted by +0.5, so truncation towards zero rounds to the nearest vertex.
        shifted = (points - self.box[0]) * (cells / (self.box[1] - self.box[0])) + 0.5
        inside = ((shifted >= 0) & (shifted < cells + 1)).all(dim=-1)
        index = torch.minimum(shifted.clamp_min(0), cells).to(torch.int32)
        strides = torch.tensor([1, rx, rx * ry], device=points.device, dtype=torch.int32)
        flat = (index * strides).sum(dim=-1, dtype=torch.int32)
        return self.occupancy.view(-1)[flat.long()] & inside

    @torch.no_grad()
    def update_occupancy(self, occupancy_alpha: float | None = None) -> float:
        """Recompute the occupancy grid from the densities (dilated by one vertex); returns the occupied fraction.

        ``occupancy_alpha`` overrides the configured threshold (a saved map is pruned harder than
        during training: faster renders for a small loss of PSNR).
        """
        rx, ry, rz = self._resolution
        threshold = self.config.occupancy_alpha if occupancy_alpha is None else occupancy_alpha
        alpha = 1.0 - torch.exp(-self.optical_depth(self.grid[:, 0].reshape(rz, ry, rx)))
        dense = F.max_pool3d((alpha >= threshold).float()[None, None], 3, stride=1, padding=1)[0, 0] > 0
        self.occupancy = dense
        nonzero = dense.nonzero()
        if len(nonzero):
            scale = torch.tensor([rx - 1, ry - 1, rz - 1], device=self.box.device, dtype=self.box.dtype)
            low = nonzero.amin(0).flip(0).to(self.box.dtype) - 1
            high = nonzero.amax(0).flip(0).to(self.box.dtype) + 1
            size = self.box[1] - self.box[0]
            self.occupied_box = torch.stack((self.box[0] + low.clamp_min(0) / scale * size, self.box[0] + torch.minimum(high, scale) / scale * size))
        return float(dense.float().mean())

    def _decode(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        unit = directions / directions.norm(dim=-1, keepdim=True)
        return self.decoder(torch.cat((features, frequency_encoding(unit, self.config.direction_frequencies)), dim=-1))

    def _ray_colour(self, diffuse: torch.Tensor, features: torch.Tensor, opacity: torch.Tensor, view_directions: torch.Tensor) -> torch.Tensor:
        """Final colour (R, 3): composited diffuse + opacity · view residual + background where transparent."""
        colour = diffuse + opacity[:, None] * self._decode(features, view_directions)
        if self.has_background:
            colour = colour + (1.0 - opacity[:, None]) * self.background
        return colour

    def render_training(
        self, origins: torch.Tensor, directions: torch.Tensor, view_directions: torch.Tensor, generator: torch.Generator | None
    ) -> torch.Tensor:
        """Differentiable colours of rays: (R, 3) each in -> rgb (R, 3) (not clamped).

        Every ray is sampled at once with a random (stratified) offset from ``generator``;
        ``view_directions`` (R, 3) are the world-frame directions the decoder sees.
        """
        step = self.voxel_size * self.config.step_ratio
        t_entry, t_exit = ray_box_intersection(origins, directions, self.occupied_box)
        norm = directions.norm(dim=-1)
        dt = step / norm
        count = int(((t_exit - t_entry) / dt).clamp_min(0).max().ceil().item()) + 1
        jitter = torch.rand(origins.shape[0], 1, generator=generator, device=origins.device) if generator is not None else 0.5
        t = t_entry[:, None] + (torch.arange(count, device=origins.device)[None] + jitter) * dt[:, None]
        valid = t < t_exit[:, None]
        ray_index, sample_index = valid.nonzero(as_tuple=True)
        points = origins[ray_index] + t[ray_index, sample_index, None] * directions[ray_index]
        keep = self.occupied(points)
        ray_index, sample_index, points = ray_index[keep], sample_index[keep], points[keep]
        return self._composite(ray_index, sample_index, points, (origins.shape[0], count), view_directions)

    def _composite(
        self, ray_index: torch.Tensor, sample_index: torch.Tensor, points: torch.Tensor, shape: tuple[int, int],
        view_directions: torch.Tensor,
    ) -> torch.Tensor:
        values = self.sample_grid(points)
        depth = torch.zeros(shape, device=points.device, dtype=values.dtype).index_put((ray_index, sample_index), self.optical_depth(values[:, 0]))
        weights, _ = weights_from_optical_depth(depth)
        sample_weights = weights[ray_index, sample_index][:, None]
        rays = shape[0]
        channels = torch.zeros(rays, 3 + self.config.features, device=points.device, dtype=values.dtype)
        shaded = torch.cat((torch.sigmoid(values[:, 1:4]), values[:, 4:]), dim=-1)
        channels = channels.index_add(0, ray_index, sample_weights * shaded)
        return self._ray_colour(channels[:, :3], channels[:, 3:], weights.sum(dim=-1), view_directions)

    def _coarse_occupancy(self) -> torch.Tensor:
        """(Cz, Cy, Cx) bool: coarse cells holding an occupied vertex, dilated by one cell (cached)."""
        key = (self.occupancy.data_ptr(), self.occupancy._version, self.occupancy.shape)
        if getattr(self, "_coarse_key", None) != key:
            factor = self.config.coarse_factor
            cells = F.max_pool3d(self.occupancy.float()[None, None], factor, stride=factor, ceil_mode=True)
            self._coarse = F.max_pool3d(cells, 3, stride=1, padding=1)[0, 0] > 0
            self._coarse_key = key
        return self._coarse

    def _occupied_span(self, origins: torch.Tensor, directions: torch.Tensor, t_entry: torch.Tensor, t_exit: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Narrow each ray's [t_entry, t_exit] to the stretch that crosses occupied coarse cells.

        Samples one point per coarse-cell length: every point of the ray is within half a cell of
        a sample, so a ray through an occupied cell has a sample in that cell or a neighbour, and
        the dilation marks the neighbours. Rays crossing no occupied cell get an empty span.
        """
        coarse = self._coarse_occupancy()
        cz, cy, cx = coarse.shape
        cell = self.voxel_size * self.config.coarse_factor
        dt = cell / directions.norm(dim=-1)
        count = int(((t_exit - t_entry) / dt).clamp_min(0).max().ceil().item()) + 1
        t = t_entry[:, None] + torch.arange(count, device=origins.device)[None] * dt[:, None]
        points = origins[:, None] + t[..., None] * directions[:, None]
        index = ((points - self.box[0]) / cell).long()
        inside = (t <= t_exit[:, None]) & (index >= 0).all(dim=-1) & (index[..., 0] < cx) & (index[..., 1] < cy) & (index[..., 2] < cz)
        index = index.clamp_min(0)
        flat = (index[..., 2].clamp_max(cz - 1) * cy + index[..., 1].clamp_max(cy - 1)) * cx + index[..., 0].clamp_max(cx - 1)
        hit = coarse.view(-1)[flat] & inside
        any_hit = hit.any(dim=-1)
        first = torch.argmax(hit.int(), dim=-1)
        last = count - 1 - torch.argmax(hit.flip(-1).int(), dim=-1)
        start = torch.maximum(t_entry, t.gather(1, first[:, None])[:, 0] - dt)
        stop = torch.minimum(t_exit, t.gather(1, last[:, None])[:, 0] + dt)
        return start, torch.where(any_hit, stop, start)

    @torch.no_grad()
    def render(self, origins: torch.Tensor, directions: torch.Tensor, view_directions: torch.Tensor) -> torch.Tensor:
        """Colours of rays without gradients, marching in blocks with early termination: (R, 3) in [0, 1]."""
        rays = origins.shape[0]
        step = self.voxel_size * self.config.step_ratio
        t_entry, t_exit = ray_box_intersection(origins, directions, self.occupied_box)
        t_entry, t_exit = self._occupied_span(origins, directions, t_entry, t_exit)
        dt = step / directions.norm(dim=-1)
        counts = ((t_exit - t_entry) / dt).clamp_min(0).ceil().long()
        log_transmittance = torch.zeros(rays, device=origins.device)
        channels = torch.zeros(rays, 3 + self.config.features, device=origins.device)
        active = (counts > 0).nonzero(as_tuple=True)[0]
        block = self.config.block_samples
        offsets = torch.arange(block, device=origins.device) + 0.5
        start = 0
        stop_log = math.log(self.config.termination_transmittance)
        while len(active):
            k = start + offsets
            t = t_entry[active, None] + k[None] * dt[active, None]
            candidates = origins[active, None] + t[..., None] * directions[active, None]
            keep = (t < t_exit[active, None]) & self.occupied(candidates.view(-1, 3)).view(t.shape)
            local_ray, sample = keep.nonzero(as_tuple=True)
            points = candidates[local_ray, sample]
            if len(points):
                values = self.sample_grid(points)
                depth = torch.zeros(len(active), block, device=origins.device).index_put((local_ray, sample), self.optical_depth(values[:, 0]))
                weights, _ = weights_from_optical_depth(depth)
                weights = weights * torch.exp(log_transmittance[active])[:, None]
                shaded = torch.cat((torch.sigmoid(values[:, 1:4]), values[:, 4:]), dim=-1)
                channels.index_add_(0, active[local_ray], weights[local_ray, sample][:, None] * shaded)
                log_transmittance[active] -= depth.sum(dim=-1)
            start += block
            alive = (log_transmittance[active] > stop_log) & (counts[active] > start)
            active = active[alive]
        opacity = 1.0 - torch.exp(log_transmittance)
        return self._ray_colour(channels[:, :3], channels[:, 3:], opacity, view_directions).clamp(0.0, 1.0)
