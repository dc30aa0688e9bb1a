"""The particle clouds and the stage profile of ``locnerf bench render``.

Clouds (``--cloud``), N poses in the map frame:

* ``views``: reference poses of the map (drawn with replacement) moved by ~2 cm: particles spread
  over the map's views, each near one of them (the default; the figures before ``--cloud`` existed);
* ``converged``: within 1 cm and 0.6° (one standard deviation per axis) of the map's first
  reference pose, as a tracking cloud after convergence;
* ``spread``: a global start: positions uniform in the map's camera bounds, orientations of random
  reference views turned by a uniform yaw about the map's up axis (gravity known, yaw unknown).

The profile (``--profile``) runs the update step the worker runs (rays from poses and pixels,
render, likelihood: :func:`locnerf.filter.measurement.particle_log_likelihoods`, and with
``--depth`` the depth rays' surface render) under ``torch.profiler`` and sums the CPU time of the
stages the code labels with ``record_function`` (``update: ...``, ``render: ...``, ``march: ...``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import torch
from torch.profiler import ProfilerActivity, profile

from locnerf.geometry import se3_exp
from locnerf.geometry.conversions import axis_angle_to_matrix

CLOUDS = ("views", "converged", "spread")
STAGE_PREFIXES = ("update: ", "render: ", "march: ")
"""Labels of the update step's stages (``torch.profiler.record_function`` in the filter, field and marcher)."""


def cloud_poses(radiance_map, cloud: str, particles: int, generator: torch.Generator) -> torch.Tensor:  # noqa: ANN001
    """(N, 4, 4) float32 poses of the cloud ``cloud`` (module docstring) on the CPU."""
    poses = radiance_map.reference_poses().float()
    if cloud == "views":
        choice = torch.randint(0, len(poses), (particles,), generator=generator)
        T_world_cam = poses[choice].clone()
        T_world_cam[:, :3, 3] += 0.02 * torch.randn(particles, 3, generator=generator)
        return T_world_cam
    if cloud == "converged":
        sigma = torch.tensor([0.01] * 3 + [0.01] * 3, dtype=torch.float64)
        return (poses[0].double()[None] @ se3_exp(torch.randn(particles, 6, dtype=torch.float64, generator=generator) * sigma)).float()
    if cloud == "spread":
        bounds = radiance_map.camera_bounds().float()
        choice = torch.randint(0, len(poses), (particles,), generator=generator)
        yaw = (2 * torch.rand(particles, generator=generator) - 1) * math.pi
        up = torch.tensor(radiance_map.normalization.up, dtype=torch.float32).expand(particles, 3)
        T_world_cam = poses[choice].clone()
        T_world_cam[:, :3, :3] = axis_angle_to_matrix(up, yaw) @ T_world_cam[:, :3, :3]
        T_world_cam[:, :3, 3] = bounds[0] + torch.rand(particles, 3, generator=generator) * (bounds[1] - bounds[0])
        return T_world_cam
    raise ValueError(f"cloud {cloud!r}: expected one of {CLOUDS}")


def stage_profile(update: Callable[[], object], repeats: int) -> dict[str, float]:
    """CPU milliseconds per call of ``update`` in each labelled stage (inclusive of the stages inside it), and
    ``"update step (wall)"``: the wall time per call, over ``repeats`` profiled calls after one untimed call."""
    update()
    with profile(activities=[ProfilerActivity.CPU]) as profiler:
        start = time.perf_counter()
        for _ in range(repeats):
            update()
        wall = time.perf_counter() - start
    stages = {event.key: event.cpu_time_total / 1000.0 / repeats for event in profiler.key_averages() if event.key.startswith(STAGE_PREFIXES)}
    return dict(sorted(stages.items(), key=lambda item: -item[1])) | {"update step (wall)": 1000.0 * wall / repeats}


def marcher_differences(radiance_map, origins: torch.Tensor, directions: torch.Tensor) -> dict[str, float]:  # noqa: ANN001
    """Largest and mean absolute differences between the compiled and the torch marcher's surface renders of the same
    rays (R, 3) x2 on a grid map: colour, opacity, and surface point (map units, rays at least 1 % opaque)."""
    field = radiance_map.field
    chosen = field.fused_march
    try:
        field.fused_march = False
        colour_torch, point_torch, opacity_torch = radiance_map.render_surface(origins, directions)
        field.fused_march = True
        colour, point, opacity = radiance_map.render_surface(origins, directions)
    finally:
        field.fused_march = chosen
    seen = opacity_torch > 0.01
    point_difference = (point - point_torch)[seen].abs()
    return {
        "colour_max": float((colour - colour_torch).abs().max()),
        "colour_mean": float((colour - colour_torch).abs().mean()),
        "opacity_max": float((opacity - opacity_torch).abs().max()),
        "point_max": float(point_difference.max()) if len(point_difference) else 0.0,
    }
