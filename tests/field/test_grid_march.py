"""The skip marcher of the grid field: distance grid, visited samples, and colours against dense float64 sampling."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.field.grid_march import SkipTable, chebyshev_distance, march
from locnerf.render.volume import ray_box_intersection


def _random_occupancy(generator: torch.Generator, shape: tuple[int, int, int], fraction: float) -> torch.Tensor:
    return torch.rand(shape, generator=generator) < fraction


def test_chebyshev_distance_matches_brute_force(generator: torch.Generator) -> None:
    occupancy = _random_occupancy(generator, (9, 10, 11), 0.01)
    occupancy[0, 0, 0] = True
    vertices = torch.stack(torch.meshgrid(*(torch.arange(n) for n in occupancy.shape), indexing="ij"), dim=-1).reshape(-1, 3)
    occupied = vertices[occupancy.reshape(-1)]
    expected = (vertices[:, None] - occupied[None]).abs().amax(dim=-1).amin(dim=-1).clamp_max(5).reshape(occupancy.shape)
    assert torch.equal(chebyshev_distance(occupancy, 5), expected.to(torch.uint8))
    assert torch.equal(chebyshev_distance(torch.zeros(3, 4, 5, dtype=torch.bool), 7), torch.full((3, 4, 5), 7, dtype=torch.uint8))
    with pytest.raises(ValueError, match="cap must be in 1..255, got 0"):
        chebyshev_distance(occupancy, 0)


@pytest.mark.parametrize("cap", [1, 3, 16])
def test_marcher_shades_exactly_the_occupied_samples(generator: torch.Generator, cap: int) -> None:
    """Per ray, the samples shaded equal those of a dense scan whose nearest vertex is occupied."""
    shape = (14, 12, 16)  # (Z, Y, X)
    occupancy = _random_occupancy(generator, shape, 0.004)
    occupancy[5:8, 4:9, 6:9] = True
    table = SkipTable(chebyshev_distance(occupancy, cap))
    largest = torch.tensor([shape[2] - 1, shape[1] - 1, shape[0] - 1], dtype=torch.float32)
    for _ in range(40):
        start = torch.rand(1, 3, generator=generator) * largest
        step = torch.randn(1, 3, generator=generator) * 0.4
        lattice = start + torch.arange(80)[:, None] * step
        count = int(((lattice >= 0) & (lattice <= largest)).all(dim=-1).long().cumprod(0).sum())  # samples in the grid
        visited: list[torch.Tensor] = []

        def record(position: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            visited.append(position)
            return torch.zeros(len(position)), torch.zeros(len(position), 1)

        march(start, step, torch.tensor([count]), table, record, channels=1, termination_transmittance=1e-3, block=4)
        shaded = torch.cat(visited) if visited else torch.zeros(0, 3)
        shaded_k = (((shaded - start) @ step[0]) / step[0].dot(step[0])).round().long().sort().values
        nearest = (lattice[:count] + 0.5).floor().long()
        expected_k = occupancy[nearest[:, 2], nearest[:, 1], nearest[:, 0]].nonzero()[:, 0]
        assert torch.equal(shaded_k, expected_k)
    with pytest.raises(ValueError, match="positive numbers of samples, got 4 and 0"):
        march(start, step, torch.tensor([1]), table, record, channels=1, termination_transmittance=1e-3, block=4, min_jump=0)


def _blob_field(generator: torch.Generator, termination: float, render_step_factor: float) -> GridField:
    """A 20³ grid, transparent except two dense blobs with random colours and features."""
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    config = GridFieldConfig(voxels=20**3, features=4, termination_transmittance=termination, render_step_factor=render_step_factor)
    field = GridField(box, config, background=(1.0, 1.0, 1.0))
    rx, ry, rz = field.resolution
    axes = [torch.linspace(-1.0, 1.0, n) for n in (rz, ry, rx)]
    z, y, x = torch.meshgrid(*axes, indexing="ij")
    inside = ((x - 0.3) ** 2 + y**2 + (z - 0.2) ** 2 < 0.2) | ((x + 0.4).abs().maximum((y + 0.3).abs()).maximum(z.abs()) < 0.3)
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator))
        field.grid[:, 0] = torch.where(inside.reshape(-1), 9.0 + 2.0 * torch.randn(inside.numel(), generator=generator), torch.full((inside.numel(),), -30.0))
        for parameter in field.decoder.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))
    field.update_occupancy()
    return field.eval()


def _rays(generator: torch.Generator, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays from a sphere of radius 3 towards random points near the centre, with non-unit directions."""
    origins = F.normalize(torch.randn(count, 3, generator=generator), dim=-1) * 3.0
    targets = 0.3 * torch.randn(count, 3, generator=generator)
    scale = 0.5 + torch.rand(count, 1, generator=generator)
    return origins, (targets - origins) * scale


def _dense_reference(field: GridField, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Float64 colours (R, 3), opacities (R,) and weighted sample positions Σ w x (R, 3) from every
    lattice sample t_entry + (k + ½)·δt, composited in a loop.

    δt is the render step (``render_step_factor`` training steps), σ·δ scaled to match.
    """
    field = field.double()
    origins, directions = origins.double(), directions.double()
    box = field.box
    rx, ry, rz = field.resolution
    cells = torch.tensor([rx - 1, ry - 1, rz - 1], dtype=torch.float64)
    volume = field.grid.detach().t().reshape(1, -1, rz, ry, rx)
    t_entry, t_exit = ray_box_intersection(origins, directions, field.occupied_box)
    factor = field.config.render_step_factor
    dt = field.voxel_size * field.config.step_ratio * factor / directions.norm(dim=-1)
    transmittance = torch.ones(len(origins), dtype=torch.float64)
    composited = torch.zeros(len(origins), 3 + field.config.features, dtype=torch.float64)
    weighted_points = torch.zeros(len(origins), 3, dtype=torch.float64)
    k = 0
    while True:
        t = t_entry + (k + 0.5) * dt
        valid = t < t_exit
        if not valid.any():
            break
        points = origins + t[:, None] * directions
        nearest = torch.floor((points - box[0]) / (box[1] - box[0]) * cells + 0.5).long()
        nearest = torch.minimum(nearest.clamp_min(0), cells.long())
        occupied = field.occupancy[nearest[:, 2], nearest[:, 1], nearest[:, 0]] & valid
        grid_points = (2.0 * (points - box[0]) / (box[1] - box[0]) - 1.0).view(1, 1, 1, -1, 3)
        values = F.grid_sample(volume, grid_points, align_corners=True, padding_mode="border").view(volume.shape[1], -1).t()
        sigma_delta = torch.where(occupied, F.softplus(values[:, 0] + field.density_shift) * field.config.step_ratio * factor, 0.0)
        alpha = 1.0 - torch.exp(-sigma_delta)
        composited += (transmittance * alpha)[:, None] * torch.cat((torch.sigmoid(values[:, 1:4]), values[:, 4:]), dim=-1)
        weighted_points += (transmittance * alpha)[:, None] * points
        transmittance = transmittance * (1.0 - alpha)
        k += 1
    with torch.no_grad():
        colour = field._ray_colour(composited[:, :3], composited[:, 3:], 1.0 - transmittance, directions)
    field.float()
    return colour.clamp(0.0, 1.0), 1.0 - transmittance, weighted_points


@pytest.mark.parametrize("fused", [True, False], ids=["fused", "torch"])
@pytest.mark.parametrize("render_step_factor", [1.0, 2.0])
def test_render_matches_dense_float64_sampling(generator: torch.Generator, render_step_factor: float, fused: bool) -> None:
    """Skipping changes nothing: float32 marcher (the compiled per-ray loop, or the batched torch
    marcher that GPUs run) vs float64 dense scan without early termination.

    Tolerance 1e-4: float32 rounding of the lookups, compositing and decoder (the float32 dense
    scan of ``render_training`` is itself ~2e-5 off). Which samples are shaded is checked exactly
    by the test above.
    """
    field = _blob_field(generator, termination=1e-12, render_step_factor=render_step_factor)
    field.fused_march = fused
    assert 0.005 < float(field.occupancy.float().mean()) < 0.2  # sparse enough for the skips to matter
    origins, directions = _rays(generator, 300)
    reference, opacity, _ = _dense_reference(field, origins, directions)
    rendered = field.render(origins, directions, directions)
    assert 0.2 < float((opacity > 0.5).float().mean()) < 0.8  # a fair share of the rays hit a blob, others miss
    torch.testing.assert_close(rendered.double(), reference, atol=1e-4, rtol=0)
    # Early termination at T < 1e-3 changes a colour by at most about the transmittance it drops.
    terminated = GridField(field.box, field.config.model_copy(update={"termination_transmittance": 1e-3}), (1.0, 1.0, 1.0))
    terminated.load_state_dict(field.state_dict())
    terminated.fused_march = fused
    assert float((terminated.render(origins, directions, directions).double() - reference).abs().max()) < 5e-3


@pytest.mark.parametrize("fused", [True, False], ids=["fused", "torch"])
def test_render_surface_matches_dense_float64_sampling(generator: torch.Generator, fused: bool) -> None:
    """The surface render: the colours of :meth:`GridField.render`, the opacity and expected point
    ``Σ w x / Σ w`` of a float64 dense scan (tolerance 1e-4 in opacity, 1e-3 map units in the point of
    rays at least 1 % opaque: float32 compositing), and the ray's origin where it met nothing."""
    field = _blob_field(generator, termination=1e-12, render_step_factor=2.0)
    field.fused_march = fused
    origins, directions = _rays(generator, 300)
    _, reference_opacity, weighted_points = _dense_reference(field, origins, directions)
    colour, points, opacity = field.render_surface(origins, directions, directions)
    torch.testing.assert_close(colour, field.render(origins, directions, directions))
    torch.testing.assert_close(opacity.double(), reference_opacity, atol=1e-4, rtol=0)
    seen = reference_opacity > 0.01
    assert int(seen.sum()) > 50
    expected = weighted_points[seen] / reference_opacity[seen, None]
    torch.testing.assert_close(points[seen].double(), expected, atol=1e-3, rtol=0)
    missed = opacity == 0
    assert bool(missed.any())
    torch.testing.assert_close(points[missed], origins[missed])


@pytest.mark.parametrize("render_step_factor", [1.0, 2.0])
def test_fused_marcher_agrees_with_torch_marcher_when_terminating(generator: torch.Generator, render_step_factor: float) -> None:
    """With early termination on (T < 1e-3, the maps' setting) the compiled loop stops at the sample where
    the transmittance is spent, the torch marcher at the end of that block: colours, opacities and the surface
    points of rays at least 1 % opaque agree to within the termination transmittance (2e-3 allows for the view
    features' magnitude); a ray that terminates in neither is the same to float32 rounding."""
    field = _blob_field(generator, termination=1e-3, render_step_factor=render_step_factor)
    origins, directions = _rays(generator, 400)
    fused = field.render_surface(origins, directions, directions)
    field.fused_march = False
    batched = field.render_surface(origins, directions, directions)
    torch.testing.assert_close(fused[0], batched[0], atol=2e-3, rtol=0)
    torch.testing.assert_close(fused[2], batched[2], atol=2e-3, rtol=0)
    seen = batched[2] > 0.01  # a surface point is defined (Σ w x / Σ w) where the ray met something
    torch.testing.assert_close(fused[1][seen], batched[1][seen], atol=2e-3, rtol=0)
    clear = batched[2] < 0.99  # never came near the termination threshold
    assert int(clear.sum()) > 50
    torch.testing.assert_close(fused[0][clear], batched[0][clear], atol=1e-5, rtol=0)


def test_fused_marcher_threads_give_the_same_colours(generator: torch.Generator) -> None:
    """Rays are independent: the parallel variant (2 threads) returns the serial one's colours bit for bit."""
    field = _blob_field(generator, termination=1e-3, render_step_factor=2.0)
    origins, directions = _rays(generator, 500)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        serial = field.render(origins, directions, directions)
        torch.set_num_threads(2)
        parallel = field.render(origins, directions, directions)
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(serial, parallel)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_render_matches_dense_float64_sampling(generator: torch.Generator) -> None:
    """What a GPU worker runs (the batched torch marcher on CUDA, ``--device auto``) against the CPU's
    float64 dense scan: colours and opacities within 1e-4 and surface points within 1e-3 map units,
    the tolerances of the CPU tests above (float32 rounding; the GPU's own summation order adds less)."""
    field = _blob_field(generator, termination=1e-12, render_step_factor=2.0)
    origins, directions = _rays(generator, 300)
    reference, reference_opacity, weighted_points = _dense_reference(field, origins, directions)
    field = field.to("cuda")
    colour, points, opacity = (x.cpu().double() for x in field.render_surface(origins.cuda(), directions.cuda(), directions.cuda()))
    torch.testing.assert_close(colour, reference, atol=1e-4, rtol=0)
    torch.testing.assert_close(opacity, reference_opacity, atol=1e-4, rtol=0)
    seen = reference_opacity > 0.01
    assert int(seen.sum()) > 50
    torch.testing.assert_close(points[seen], weighted_points[seen] / reference_opacity[seen, None], atol=1e-3, rtol=0)
