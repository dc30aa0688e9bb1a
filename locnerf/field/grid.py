"""The grid radiance field: a dense voxel grid of density, diffuse colour and view features.

Design (chosen by measurement on a 2-core CPU, see docs/MAPS.md): one dense grid of
``1 + 3 + F`` channels, stored vertex-major as a (V, C) table and interpolated trilinearly as a
weighted ``embedding_bag`` of the 8 corner vertices with a scatter-add backward (``_TrilinearGather``;
about twice as fast on CPU as ``grid_sample``'s 3-D backward): density (softplus with a shift so
that the initial opacity is tiny, as in DVGO), diffuse colour (sigmoid) and F view features. The
view-dependent part is deferred: the composited features of a ray and its direction go through a
tiny MLP once per ray (as in SNeRG), so the per-sample cost is one trilinear lookup. An occupancy
grid (dilated) marks where density is; the no-gradient renderer jumps over empty space with a
distance grid built from it and stops rays once their transmittance is spent (``grid_march``).
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch.profiler import record_function

from locnerf.field.encoding import frequency_encoding
from locnerf.field.grid_march import SKIP_DISTANCE_CAP, SkipTable, chebyshev_distance, march
from locnerf.field.grid_march_fused import fused_march
from locnerf.render.volume import ray_box_intersection, weights_from_optical_depth

RETIRED_CONFIG_FIELDS = ("block_samples", "coarse_factor")
"""Render tuning that older map files store in the field config (now constants of grid_march)."""
MAX_GRID_VERTICES = 2**27
"""Most vertices of a grid (512³: 6.4 GB of float32 at the default 12 channels; the default map has 128³ = 2.1M).
Map files asking for more are refused before anything is allocated."""
DECODE_CHUNK = 4096
"""Rays per call of the view decoder in no-gradient renders: its hidden layer (rays × width floats) then stays
in cache instead of being a fresh allocation of tens of MB per call (page faults cost more than the matmul)."""
MAX_FEATURES, MAX_DECODER_WIDTH, MAX_DIRECTION_FREQUENCIES = 64, 1024, 16
"""Largest view features per vertex, decoder width and direction octaves a grid field is built with."""


class GridFieldConfig(BaseModel):
    """Shape of a grid field."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    voxels: int = Field(
        128**3, gt=0, le=MAX_GRID_VERTICES, description="Target number of grid vertices (split over the axes by the box's aspect); at most 2**27."
    )
    features: int = Field(8, ge=0, le=MAX_FEATURES, description="View-feature channels per vertex, decoded per ray by the MLP.")
    decoder_width: int = Field(64, gt=0, le=MAX_DECODER_WIDTH, description="Hidden width of the per-ray view-dependent decoder.")
    direction_frequencies: int = Field(2, ge=0, le=MAX_DIRECTION_FREQUENCIES, description="Octaves of the frequency encoding of the view direction.")
    step_ratio: float = Field(0.5, gt=0, description="Sample spacing along rays, in voxels.")
    initial_alpha: float = Field(1e-4, gt=0, lt=1, description="Opacity of one step at initialisation (sets the density shift).")
    occupancy_alpha: float = Field(1e-3, gt=0, lt=1, description="A voxel is occupied when one step through it is at least this opaque.")
    termination_transmittance: float = Field(1e-3, gt=0, lt=1, description="Rays stop marching below this transmittance.")
    render_step_factor: float = Field(
        2.0, ge=1, description="No-gradient renders sample every render_step_factor · step_ratio voxels (opacity per sample scaled to match)."
    )
    voxel_aspect: tuple[float, float, float] = Field(
        (1.0, 1.0, 1.0),
        description="Voxel edge along (x, y, z) relative to each other; (1, 1, 1) is cubic. Forward-facing (NDC) maps use a coarse"
        " NDC depth (z), which is already disparity-spaced. Steps and optical depth are in voxel units, so per axis.",
    )

    @model_validator(mode="before")
    @classmethod
    def _drop_retired_fields(cls, data: Any) -> Any:
        """Map files written before the skip marcher carry its predecessor's tuning; it is ignored."""
        if isinstance(data, dict):
            return {key: value for key, value in data.items() if key not in RETIRED_CONFIG_FIELDS}
        return data


def grid_shape_for_box(box: torch.Tensor, voxels: int, aspect: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> tuple[int, int, int]:
    """(Rx, Ry, Rz) vertices per axis for about ``voxels`` vertices in all.

    Args:
        box: (2, 3) low and high corners.
        voxels: target vertex count.
        aspect: voxel edge along (x, y, z) relative to each other, all > 0.
    """
    if len(aspect) != 3 or min(aspect) <= 0:
        raise ValueError(f"voxel aspect {aspect}: expected three positive edge ratios")
    extent = (box[1] - box[0]).double() / torch.tensor(aspect, dtype=torch.float64)
    size = (float(extent.prod()) / voxels) ** (1.0 / 3.0)
    return tuple(max(2, int(math.ceil(float(e) / size)) + 1) for e in extent)  # type: ignore[return-value]


class _TrilinearGather(torch.autograd.Function):
    """``Σ_k weights[p, k] · table[index[p, k]]``: (V, C), (P, 8), (P, 8) -> (P, C), differentiable in ``table``.

    The forward pass is a weighted ``embedding_bag``; the backward pass scatters into the table's
    gradient with one accumulating ``index_put_``, which on CPU is ~1.4× faster than embedding-bag's
    own backward (that sorts the indices first; docs/MAPS.md). Positions get no gradient.
    """

    @staticmethod
    def forward(ctx, table: torch.Tensor, index: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        ctx.save_for_backward(index, weights)
        ctx.rows = table.shape[0]
        return F.embedding_bag(index, table, per_sample_weights=weights, mode="sum")

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None, None]:  # type: ignore[override]
        index, weights = ctx.saved_tensors
        channels = grad.shape[1]
        table_grad = grad.new_zeros(ctx.rows, channels)
        table_grad.index_put_((index.reshape(-1),), (weights[:, :, None] * grad[:, None, :]).reshape(-1, channels), accumulate=True)
        return table_grad, None, None


class GridField(torch.nn.Module):
    """Dense-grid field over an axis-aligned box, with its own ray marcher.

    Points and rays are in the field's space (the map frame, or NDC for forward-facing maps).
    """

    def __init__(
        self, box: torch.Tensor, config: GridFieldConfig, background: tuple[float, float, float] | None, resolution: tuple[int, int, int] | None = None
    ) -> None:
        """A zero grid over ``box`` (2, 3) with ``resolution`` (Rx, Ry, Rz) vertices, by default about
        ``config.voxels`` split over the axes by the box's aspect (:func:`grid_shape_for_box`)."""
        super().__init__()
        self.config = config
        self.register_buffer("box", box.float().clone())
        self.register_buffer("background", torch.tensor(background if background is not None else (0.0, 0.0, 0.0)))
        self.has_background = background is not None
        self.fused_march = True
        """CPU renders march with the compiled per-ray loop (False: the batched torch marcher, as on a GPU)."""
        rx, ry, rz = resolution if resolution is not None else grid_shape_for_box(box, config.voxels, config.voxel_aspect)
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
    def voxel_sizes(self) -> torch.Tensor:
        """(3,) voxel edges along x, y, z in field units."""
        cells = torch.tensor(self.resolution, device=self.box.device, dtype=self.box.dtype) - 1
        return (self.box[1] - self.box[0]) / cells

    def ray_parameter_per_voxel(self, directions: torch.Tensor) -> torch.Tensor:
        """(R,) ray-parameter increment that advances one voxel unit along rays ``directions`` (R, 3).

        Distances are measured in voxels (each axis scaled by its voxel edge), so anisotropic grids
        take per-axis steps: ``1 / ‖d ⊘ voxel_sizes‖`` (``voxel_size / ‖d‖`` for cubic voxels).
        """
        return 1.0 / (directions / self.voxel_sizes).norm(dim=-1)

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
        cells = torch.tensor([r - 1 for r in self._resolution], device=points.device, dtype=points.dtype)
        return self.interpolate_vertices((points - self.box[0]) * (cells / (self.box[1] - self.box[0])))

    def interpolate_vertices(self, position: torch.Tensor) -> torch.Tensor:
        """Trilinear grid values at vertex coordinates: position (P, 3) (x, y, z; clamped to the grid) -> (P, 4 + F)."""
        rx, ry, rz = self._resolution
        device = position.device
        cells = torch.tensor([rx - 1, ry - 1, rz - 1], device=device, dtype=position.dtype)
        position = torch.clamp(position, torch.zeros_like(cells), cells)
        corner = torch.minimum(position.floor(), cells - 1)
        fx, fy, fz = (position - corner).t().contiguous()
        base = (corner.long() * torch.tensor([1, rx, rx * ry], device=device)).sum(dim=-1)
        offsets = torch.tensor([(dz * ry + dy) * rx + dx for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], device=device)
        # weight of corner (dx, dy, dz) = Π_axis (f if bit else 1 - f), in the order of ``offsets``
        gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
        zy = (gz * gy, gz * fy, fz * gy, fz * fy)
        weights = torch.stack([w * x for w in zy for x in (gx, fx)], dim=-1)
        return _TrilinearGather.apply(self.grid, base[:, None] + offsets, weights)

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

    def _training_samples(
        self, origins: torch.Tensor, directions: torch.Tensor, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
        """Stratified samples of rays (R, 3) x2 in occupied voxels of the occupied box.

        Returns:
            ray index (S,), sample index (S,), points (S, 3), ray parameters (S,), samples per ray
            of the dense lattice (the width of the compositing table).
        """
        t_entry, t_exit = ray_box_intersection(origins, directions, self.occupied_box)
        dt = self.config.step_ratio * self.ray_parameter_per_voxel(directions)
        count = int(((t_exit - t_entry) / dt).clamp_min(0).max().ceil().item()) + 1
        jitter = torch.rand(origins.shape[0], 1, generator=generator, device=origins.device) if generator is not None else 0.5
        t = t_entry[:, None] + (torch.arange(count, device=origins.device)[None] + jitter) * dt[:, None]
        valid = t < t_exit[:, None]
        ray_index, sample_index = valid.nonzero(as_tuple=True)
        t = t[ray_index, sample_index]
        points = origins[ray_index] + t[:, None] * directions[ray_index]
        keep = self.occupied(points)
        return ray_index[keep], sample_index[keep], points[keep], t[keep], count

    def render_training(
        self, origins: torch.Tensor, directions: torch.Tensor, view_directions: torch.Tensor, generator: torch.Generator | None
    ) -> torch.Tensor:
        """Differentiable colours of rays: (R, 3) each in -> rgb (R, 3) (not clamped).

        Every ray is sampled at once with a random (stratified) offset from ``generator``;
        ``view_directions`` (R, 3) are the world-frame directions the decoder sees.
        """
        ray_index, sample_index, points, _, count = self._training_samples(origins, directions, generator)
        return self._composite(ray_index, sample_index, points, (origins.shape[0], count), view_directions)

    def render_training_depth(
        self, origins: torch.Tensor, directions: torch.Tensor, generator: torch.Generator | None, free_space_until: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Differentiable expected ray parameter of rays (R, 3) x2 -> (R,): ``Σ w_k t_k + (1 - Σ w_k) · t_box``,
        and, when ``free_space_until`` (R,) is given, each ray's weight in front of it, ``Σ_{t_k < free_space_until} w_k`` (R,).

        The transmittance left after the last sample ends the ray where it leaves the grid's box
        (``t_box``), so a transparent ray reads "far" rather than 0: a depth loss then pulls
        density towards the observed surface instead of rewarding empty rays. With directions of
        camera z = -1 (:mod:`locnerf.render.rays`) the parameter is the depth along the optical axis.
        The weight in front of a depth reading is what a free-space loss pushes to 0: an expected
        depth alone is also matched by a floater in front of the surface balanced by density behind it.
        """
        ray_index, sample_index, points, t, count = self._training_samples(origins, directions, generator)
        optical = self.optical_depth(self.sample_grid(points)[:, 0])
        table = torch.zeros((origins.shape[0], count), device=points.device, dtype=optical.dtype).index_put((ray_index, sample_index), optical)
        weights, _ = weights_from_optical_depth(table)
        sample_weights = weights[ray_index, sample_index]
        expected = torch.zeros(origins.shape[0], device=points.device, dtype=optical.dtype).index_add(0, ray_index, sample_weights * t)
        _, t_box = ray_box_intersection(origins, directions, self.box)
        in_front = None
        if free_space_until is not None:
            ahead = t < free_space_until[ray_index]
            in_front = torch.zeros(origins.shape[0], device=points.device, dtype=optical.dtype).index_add(0, ray_index[ahead], sample_weights[ahead])
        return expected + (1.0 - weights.sum(dim=-1)) * t_box, in_front

    @torch.no_grad()
    def seed_density(self, points: torch.Tensor, alpha: float) -> float:
        """Start from known surface points (P, 3) (field space, e.g. back-projected depth): the vertex
        nearest to each gets one-step opacity ``alpha`` (others keep theirs) and the occupancy is
        recomputed from the densities, so training samples only near the seeds from the first step.

        Returns:
            the occupied fraction of the grid afterwards.
        """
        if not 0 < alpha < 1:
            raise ValueError(f"alpha={alpha}: expected a one-step opacity in (0, 1)")
        rx, ry, rz = self._resolution
        cells = torch.tensor([rx - 1, ry - 1, rz - 1], device=points.device, dtype=points.dtype)
        vertex = ((points - self.box[0]) * (cells / (self.box[1] - self.box[0]))).round()
        inside = ((vertex >= 0) & (vertex <= cells)).all(dim=-1)
        flat = (vertex[inside].long() * torch.tensor([1, rx, rx * ry], device=points.device)).sum(dim=-1)
        raw = math.log(math.expm1(-math.log(1.0 - alpha) / self.config.step_ratio)) - self.density_shift
        self.grid.data[flat.unique(), 0] = raw
        return self.update_occupancy()

    def _composite(
        self,
        ray_index: torch.Tensor,
        sample_index: torch.Tensor,
        points: torch.Tensor,
        shape: tuple[int, int],
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

    def _skip_table(self) -> SkipTable:
        """Skip table of the occupancy for the no-gradient renderer (cached per occupancy state)."""
        key = (self.occupancy.data_ptr(), self.occupancy._version, self.occupancy.shape)
        if getattr(self, "_skip_key", None) != key:
            self._skip = SkipTable(chebyshev_distance(self.occupancy, SKIP_DISTANCE_CAP))
            self._skip_key = key
        return self._skip

    def _shade(self, position: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Render-step optical depth (P,) and composited channels (P, 3 + F) at vertex coordinates (P, 3)."""
        values = self.interpolate_vertices(position)
        values[:, 1:4].sigmoid_()
        return self.optical_depth(values[:, 0]) * self.config.render_step_factor, values[:, 1:]

    def _shade_with_position(self, position: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """As :meth:`_shade`, with the vertex coordinates (P, 3) appended to the channels (so they composite too)."""
        optical, channels = self._shade(position)
        return optical, torch.cat((channels, position), dim=-1)

    def _march_rays(self, origins: torch.Tensor, directions: torch.Tensor, with_position: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Composited channels (R, 3 + F [+ 3 vertex coordinates]), log transmittance (R,) and the
        field-to-vertex scale (3,) of rays (R, 3) x2: the sampling of :meth:`render`, marched by the
        compiled per-ray loop on the CPU (:mod:`grid_march_fused`, unless ``fused_march`` is False)
        and by the batched torch marcher elsewhere (:func:`grid_march.march`)."""
        with record_function("render: ray setup (box, lattice)"):
            cells = torch.tensor([r - 1 for r in self._resolution], device=origins.device, dtype=origins.dtype)
            to_vertices = cells / (self.box[1] - self.box[0])
            t_entry, t_exit = ray_box_intersection(origins, directions, self.occupied_box)
            dt = self.config.step_ratio * self.config.render_step_factor * self.ray_parameter_per_voxel(directions)
            # Sample k at t_entry + (k + ½)·dt lies before the exit while k < (t_exit - t_entry)/dt - ½.
            counts = ((t_exit - t_entry) / dt - 0.5).clamp_min(0).ceil().long()
            start = (origins + (t_entry + 0.5 * dt)[:, None] * directions - self.box[0]) * to_vertices
            step = dt[:, None] * directions * to_vertices
        if self.fused_march and origins.device.type == "cpu":
            composited, log_transmittance = fused_march(
                start,
                step,
                counts,
                self._skip_table(),
                self.grid,
                self._resolution,
                self.density_shift,
                self.config.step_ratio * self.config.render_step_factor,
                self.config.termination_transmittance,
                with_position,
            )
            return composited, log_transmittance, to_vertices
        composited, log_transmittance = march(
            start,
            step,
            counts,
            self._skip_table(),
            self._shade_with_position if with_position else self._shade,
            3 + self.config.features + (3 if with_position else 0),
            self.config.termination_transmittance,
        )
        return composited, log_transmittance, to_vertices

    def _final_colour(self, composited: torch.Tensor, log_transmittance: torch.Tensor, view_directions: torch.Tensor) -> torch.Tensor:
        """rgb (R, 3) in [0, 1] from composited (R, 3 + F) channels; rays that met nothing are the background (or black)."""
        with record_function("render: view decoder (MLP per ray)"):
            colour = self.background.expand(len(composited), 3).clone() if self.has_background else composited.new_zeros(len(composited), 3)
            hit = (log_transmittance < 0).nonzero(as_tuple=True)[0]
            for chunk in hit.split(DECODE_CHUNK):
                opacity = -torch.expm1(log_transmittance[chunk])
                colour[chunk] = self._ray_colour(composited[chunk, :3], composited[chunk, 3:], opacity, view_directions[chunk])
            return colour.clamp(0.0, 1.0)

    @torch.no_grad()
    def render(self, origins: torch.Tensor, directions: torch.Tensor, view_directions: torch.Tensor) -> torch.Tensor:
        """Colours of rays without gradients: (R, 3) each in -> rgb (R, 3) in [0, 1].

        Samples the lattice t_entry + (k + ½)·δt through the occupied box, as :meth:`render_training`
        does without jitter but with δt ``render_step_factor`` times longer (and σ·δ to match); empty
        stretches are jumped over with the Chebyshev distance grid and rays stop once their
        transmittance is spent (:func:`grid_march.march`).
        """
        composited, log_transmittance, _ = self._march_rays(origins, directions, with_position=False)
        return self._final_colour(composited, log_transmittance, view_directions)

    @torch.no_grad()
    def render_surface(self, origins: torch.Tensor, directions: torch.Tensor, view_directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """What :meth:`render` gives, plus where each ray meets the scene: (R, 3) each in ->
        rgb (R, 3), expected surface point (R, 3) in field space (``Σ w_k x_k / Σ w_k``; the ray's
        origin where it met nothing) and opacity ``Σ w_k`` (R,)."""
        composited, log_transmittance, to_vertices = self._march_rays(origins, directions, with_position=True)
        colour = self._final_colour(composited[:, :-3], log_transmittance, view_directions)
        opacity = -torch.expm1(log_transmittance)
        hit = (opacity > 0)[:, None]
        vertex = composited[:, -3:] / torch.where(hit, opacity[:, None], torch.ones_like(opacity[:, None]))
        points = torch.where(hit, vertex / to_vertices + self.box[0], origins)
        return colour, points, opacity
