"""Building a grid map from posed images: Adam on the photometric loss of random ray batches.

Coarse to fine: the grid starts with 1/8 of its vertices and is trilinearly upsampled once; the
occupancy grid is refreshed periodically so that empty space stops costing samples. Training stops
after ``steps`` steps or ``minutes`` of wall time, whichever comes first; the learning rates decay
exponentially with the progress fraction. A build of a fixed number of steps with ``threads = 1``
is bit-reproducible from its seed (several intra-op threads sum gradients in a varying order).

RGB-D data (images with ``depths``, e.g. 7-Scenes) add an expected-depth loss on random rays of
the depth camera (``depth_weight``) and, optionally, start the density from the back-projected
depth points (``depth_seed_alpha``): a room seen from inside then has its walls from the first
step, and training samples only near them; the depth readings also become the map's surface-distance
layer (``surface_distance``). ``use_depth=False`` trains on colour only. RGB-D data
default to a coarser grid with total variation (``room``). Options, off by default: a per-image
exposure transform of the training renders (``exposure_learning_rate``) and total variation
(``tv_weight``).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from typing import Any

import torch
from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from locnerf.data.colour_camera import METADATA_KEY, calibrate_colour_camera, with_colour_camera
from locnerf.data.posed_images import PosedImages
from locnerf.errors import DatasetError
from locnerf.field.grid import GridField, GridFieldConfig, grid_shape_for_box
from locnerf.field.grid_map import GridMap
from locnerf.field.map_info import MapInfo
from locnerf.field.surface_distance import SurfaceDistanceConfig
from locnerf.render.image import render_image
from locnerf.render.rays import pixel_grid, rays_from_poses_and_pixels
from locnerf.train.depth_rays import depth_loss, depth_training_rays
from locnerf.train.exposure import ImageExposure
from locnerf.train.metrics import psnr, psnr_from_mse, ssim
from locnerf.train.surface_layer import surface_distance_of_frames
from locnerf.train.total_variation import grid_total_variation

logger = logging.getLogger(__name__)

TRAINING_POSE_TOLERANCE = 1e-6
"""Largest difference of any camera-to-world entry (rotation, or translation in map units) at which a view is a training frame."""


class ForwardFacingConfig(BaseModel):
    """Settings that replace the general ones when the data are forward-facing (NDC rays, LLFF).

    In NDC the scene fills most of the box and every ray crosses it, so samples per ray, not
    empty space, set the cost of a step; these values were chosen with 2-minute fern builds on
    the 2-core CPU (docs/MAPS.md).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    depth_ratio: float = Field(4.0, gt=0, description="Voxel edge along NDC depth relative to x (x:y follows the image aspect): NDC depth is disparity-spaced.")
    step_ratio: float = Field(1.0, gt=0, description="Training sample spacing in voxels (the field's step_ratio).")
    initial_alpha: float = Field(0.01, gt=0, lt=1, description="One-step opacity at initialisation (the field's initial_alpha): surfaces form in fewer steps.")
    grid_learning_rate: float = Field(0.3, gt=0, description="Initial Adam learning rate of the grid.")
    batch_rays: int = Field(2048, gt=0, description="Rays per optimisation step.")
    occupancy_warmup: int = Field(30, ge=0, description="Steps before empty-space skipping starts.")
    render_step_factor: float = Field(
        1.0, ge=1, description="The field's render_step_factor: NDC maps render at the training step (fern hold-out 22.7 dB against 21.9 dB at 2×)."
    )


class RoomConfig(BaseModel):
    """Settings that replace the general ones when the data have depth images (RGB-D rooms seen from inside, 7-Scenes).

    Only where the caller left the general setting at its default (pydantic's ``model_fields_set``):
    an explicit ``voxels``, ``features``, ``tv_weight``, ``depth_weight`` or ``free_space_weight`` wins.
    Chosen with fixed-step builds of the redkitchen training split scored on test frames
    (docs/MAPS.md): test views from another trajectory than the training frames' favour a coarser,
    smoother grid (which also steps faster), no view-dependent colour (it extrapolates badly to
    directions no training frame had) and surfaces kept free of floaters in front of the depth readings.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    voxels: int = Field(64**3, gt=0, description="Grid vertices in all (redkitchen: 87×49×65, 5.6 cm voxels, against 2.8 cm at the general 128³).")
    features: int = Field(0, ge=0, description="View-feature channels per vertex (the field's features): 0, diffuse colour only.")
    tv_weight: float = Field(0.01, ge=0, description="Weight of the grid's total variation (BuildConfig.tv_weight).")
    depth_weight: float = Field(1.0, ge=0, description="Weight of the expected-depth loss (BuildConfig.depth_weight).")
    free_space_weight: float = Field(0.1, ge=0, description="Weight of the free-space loss (BuildConfig.free_space_weight).")


class BuildConfig(BaseModel):
    """How to build a grid map."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    field: GridFieldConfig = Field(default_factory=GridFieldConfig, description="Shape of the grid field.")
    steps: int = Field(20000, gt=0, description="Most optimisation steps.")
    minutes: float | None = Field(None, gt=0, description="Wall-time budget; None trains for exactly `steps` steps (reproducible).")
    batch_rays: int = Field(4096, gt=0, description="Rays per optimisation step.")
    grid_learning_rate: float = Field(0.1, gt=0, description="Initial Adam learning rate of the grid.")
    decoder_learning_rate: float = Field(2e-3, gt=0, description="Initial Adam learning rate of the view decoder.")
    final_learning_rate_factor: float = Field(0.1, gt=0, le=1, description="Learning rates at the end relative to the start.")
    coarse_fraction: float = Field(0.25, ge=0, lt=1, description="Progress fraction trained at the coarse (1/8 vertices) grid.")
    occupancy_warmup: int = Field(100, ge=0, description="Steps before empty-space skipping starts.")
    occupancy_every: int = Field(50, gt=0, description="Steps between occupancy-grid refreshes.")
    final_occupancy_alpha: float = Field(
        0.03, gt=0, lt=1, description="Occupancy threshold of the saved map (one-step opacity): prunes faint floaters so renders skip more."
    )
    seed: int = Field(0, description="Seed of ray batches and sample jitter.")
    threads: int | None = Field(
        None, ge=1, description="torch intra-op threads during the build (1: bit-reproducible from the seed); None keeps the process's setting."
    )
    use_depth: bool = Field(True, description="Use the images' depth (when they have any); False builds from colour only.")
    depth_weight: float = Field(0.1, ge=0, description="Weight of the expected-depth loss (squared error, map units²) beside the colour MSE.")
    depth_batch_rays: int = Field(2048, gt=0, description="Depth-camera rays per optimisation step for the depth loss.")
    free_space_weight: float = Field(
        0.0, ge=0, description="Weight of the free-space loss: the mean rendering weight of depth rays in front of their reading (minus the margin); 0: off."
    )
    free_space_margin: float = Field(
        2.0, ge=0, description="Voxels in front of each depth reading where the free-space loss leaves the weight alone (the surface's own spread)."
    )
    depth_seed_alpha: float | None = Field(
        0.1, gt=0, lt=1, description="One-step opacity given at the start to the vertices nearest to back-projected depth points (None: no seeding)."
    )
    depth_seed_points: int = Field(2_000_000, gt=0, description="Most depth points used for seeding (an evenly spaced subset).")
    calibrate_colour_camera: bool = Field(
        True,
        description="RGB-D data posed at the depth camera (7-Scenes): estimate the colour camera's offset from it (data/colour_camera.py),"
        " train the colour rays from the colour camera and record the offset in the map (inside the time budget).",
    )
    exposure_learning_rate: float | None = Field(
        None,
        gt=0,
        description="Adam learning rate of a per-training-image colour gain and bias applied to renders in training only"
        " (train/exposure.py: absorbs auto-exposure so the field stores one appearance); None: off.",
    )
    tv_weight: float = Field(0.0, ge=0, description="Weight of the grid's total variation (train/total_variation.py) beside the colour MSE; 0: off.")
    tv_vertices: int = Field(32768, gt=0, description="Random vertices per step at which the total variation is evaluated.")
    forward_facing: ForwardFacingConfig = Field(
        default_factory=ForwardFacingConfig, description="Replacements of the settings above for forward-facing (NDC) data."
    )
    room: RoomConfig = Field(
        default_factory=RoomConfig, description="Replacements of the settings above for RGB-D data (rooms seen from inside), unless set explicitly."
    )
    surface_distance: SurfaceDistanceConfig | None = Field(
        default_factory=SurfaceDistanceConfig,
        description="RGB-D data: the map's surface-distance layer from the depth images (field/surface_distance.py; inside the time budget,"
        " about a minute for redkitchen's 600 frames); None: no layer.",
    )


def training_rays(images: PosedImages, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every pixel ray of a posed-image set: origins (N, 3), directions (N, 3), colours (N, 3), float32."""
    pixels = pixel_grid(images.intrinsics)
    origins, directions = rays_from_poses_and_pixels(images.T_world_cam.double(), pixels.double(), images.intrinsics)
    return (
        origins.reshape(-1, 3).float().to(device),
        directions.reshape(-1, 3).float().to(device),
        images.images.reshape(-1, 3).float().to(device),
    )


def config_for(images: PosedImages, config: BuildConfig) -> BuildConfig:
    """The settings that train on ``images``: ``config`` itself, with its ``forward_facing`` values for NDC
    data, or with its ``room`` values for RGB-D data where ``config`` left the general ones at their defaults.

    NDC x and y span the image width and height, so an x:y voxel edge ratio of width:height gives
    every voxel a square pixel footprint; NDC depth takes ``depth_ratio`` times coarser voxels.
    """
    if images.depths is not None and not images.normalization.ndc:
        room = config.room
        field_defaults = {name: getattr(room, name) for name in ("voxels", "features") if name not in config.field.model_fields_set}
        defaults = {name: getattr(room, name) for name in ("tv_weight", "depth_weight", "free_space_weight") if name not in config.model_fields_set}
        return config.model_copy(update={"field": config.field.model_copy(update=field_defaults), **defaults})
    if not images.normalization.ndc:
        return config
    ndc = config.forward_facing
    aspect = (1.0, images.intrinsics.width / images.intrinsics.height, ndc.depth_ratio)
    field = config.field.model_copy(
        update={"voxel_aspect": aspect, "step_ratio": ndc.step_ratio, "initial_alpha": ndc.initial_alpha, "render_step_factor": ndc.render_step_factor}
    )
    return config.model_copy(
        update={"field": field, "grid_learning_rate": ndc.grid_learning_rate, "batch_rays": ndc.batch_rays, "occupancy_warmup": ndc.occupancy_warmup}
    )


def field_box(images: PosedImages, field_origins: torch.Tensor, field_directions: torch.Tensor) -> torch.Tensor:
    """(2, 3) box of the grid: the data's scene bounds, for NDC data widened in x and y to every training ray.

    NDC's [-1, 1]² is the reference camera's frustum; the other cameras of a forward-facing capture
    look past it (fern's rays reach x ±1.44, y ±1.29), and a grid clipped to it cannot explain
    those pixels. An NDC ray is a straight line from the near plane (t = 0) to infinity (t = 1), so
    its extent is that of its two ends. ``field_origins``, ``field_directions``: (R, 3) in field space.
    """
    box = images.scene_bounds.double().clone()
    if images.normalization.ndc:
        ends = torch.cat((field_origins, field_origins + field_directions)).double().cpu()
        box[0, :2] = torch.minimum(box[0, :2], ends[:, :2].amin(dim=0))
        box[1, :2] = torch.maximum(box[1, :2], ends[:, :2].amax(dim=0))
    return box


def _depth_rays(images: PosedImages, config: BuildConfig, info: MapInfo, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
    """The depth camera's supervised rays (origins, directions, depths) when depth is there and used; None otherwise.

    Raises:
        DatasetError: for depth with NDC data (depth along NDC rays is not the sensor's depth).
    """
    if images.depths is None or not config.use_depth:
        return None
    if info.normalization.ndc:
        raise DatasetError(f"{images.source}: depth supervision of NDC (forward-facing) maps is not supported; build with use_depth=False")
    return depth_training_rays(images, device)


def _on_colour_camera(images: PosedImages, config: BuildConfig) -> tuple[PosedImages, dict]:
    """``images`` moved onto their calibrated colour camera, and the map metadata recording it, where
    ``config`` asks for it and the data are RGB-D posed at the depth camera; otherwise as they are, and no metadata."""
    if not config.calibrate_colour_camera or images.depths is None or images.T_cam_depth is not None or images.normalization.ndc:
        return images, {}
    started = time.monotonic()
    try:
        calibration = calibrate_colour_camera(images)
    except DatasetError as error:  # too few overlapping frames (a sparse subset): the colour rays stay at the depth camera
        logger.warning("colour camera not calibrated, colour rays cast from the depth camera's poses: %s", error)
        return images, {"colour_calibration": {"skipped": str(error)}}
    metadata = {
        METADATA_KEY: calibration.T_depth_colour.tolist(),
        "colour_calibration": calibration.record(time.monotonic() - started),
    }
    return with_colour_camera(images, calibration.T_depth_colour), metadata


def _optimizer(field: GridField, exposure: ImageExposure | None, config: BuildConfig) -> torch.optim.Optimizer:
    groups = [
        {"params": [field.grid], "lr": config.grid_learning_rate, "initial_lr": config.grid_learning_rate},
        {"params": list(field.decoder.parameters()), "lr": config.decoder_learning_rate, "initial_lr": config.decoder_learning_rate},
    ]
    if exposure is not None:
        groups.append({"params": list(exposure.parameters()), "lr": config.exposure_learning_rate, "initial_lr": config.exposure_learning_rate})
    return torch.optim.Adam(
        groups,
        betas=(0.9, 0.99),
        fused=True,
        eps=1e-15,  # gradients of sparsely hit voxels are tiny; a larger eps would freeze them
    )


@contextlib.contextmanager
def intra_op_threads(threads: int | None) -> Iterator[None]:
    """torch's intra-op thread count set to ``threads`` inside the block, restored after (None: left alone)."""
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def build_map(images: PosedImages, config: BuildConfig, device: torch.device | str = "cpu", progress: bool = False) -> GridMap:
    """Train a grid map on ``images`` (the training split), with ``config.threads`` intra-op threads.

    Returns:
        the map; its metadata holds ``config`` (the settings used, after :func:`config_for`), ``steps``,
        ``seconds``, ``train_psnr`` (last batches) and ``source``.
    """
    with intra_op_threads(config.threads):
        return _train_map(images, config, torch.device(device), progress)


def _train_map(images: PosedImages, config: BuildConfig, device: torch.device, progress: bool) -> GridMap:
    """:func:`build_map`'s training loop."""
    start = time.monotonic()
    config = config_for(images, config)
    generator = torch.Generator(device=device).manual_seed(config.seed)
    torch.manual_seed(config.seed)
    images, calibration = _on_colour_camera(images, config)
    info = MapInfo(images.normalization, images.intrinsics, images.T_world_cam.double().clone(), {"source": images.source, **calibration})
    origins, directions, colours = training_rays(images, device)
    field_origins, field_directions = info.field_rays(origins, directions)
    background = (1.0, 1.0, 1.0) if images.white_background else None
    box = field_box(images, field_origins, field_directions)
    field = GridField(box.to(device), config.field, background).to(device)
    fine_resolution = field.resolution
    if config.coarse_fraction > 0:
        field.resize(grid_shape_for_box(box, config.field.voxels // 8, config.field.voxel_aspect))
    depth_rays = _depth_rays(images, config, info, device)
    surface_distance = None
    if depth_rays is not None and config.surface_distance is not None:
        surface_distance = surface_distance_of_frames(images, config.surface_distance).to(device)
    if depth_rays is not None and config.depth_seed_alpha is not None:
        d_origins, d_directions, d_observed = depth_rays
        every = max(1, len(d_observed) // config.depth_seed_points)
        points = d_origins[::every] + d_observed[::every, None] * d_directions[::every]
        occupied = field.seed_density(points, config.depth_seed_alpha)
        logger.info("seeded the density at %d depth points: %.1f %% of the grid occupied", len(points), 100 * occupied)
    exposure = ImageExposure(len(images)).to(device) if config.exposure_learning_rate is not None else None
    pixels_per_image = images.intrinsics.height * images.intrinsics.width
    optimizer = _optimizer(field, exposure, config)
    budget = config.minutes * 60.0 if config.minutes is not None else None
    bar = tqdm(total=config.steps, disable=not progress, desc="build", unit="step")
    smoothed_mse = None
    depth_history: list[float] = []
    step = 0
    while step < config.steps:
        elapsed = time.monotonic() - start
        fraction = max(step / config.steps, elapsed / budget if budget else 0.0)
        if fraction >= 1.0:
            break
        if field.resolution != fine_resolution and fraction >= config.coarse_fraction:
            field.resize(fine_resolution)
            optimizer = _optimizer(field, exposure, config)
        decay = config.final_learning_rate_factor**fraction
        for group in optimizer.param_groups:
            group["lr"] = group["initial_lr"] * decay
        if step >= config.occupancy_warmup and step % config.occupancy_every == 0:
            field.update_occupancy()
        batch = torch.randint(0, len(origins), (config.batch_rays,), generator=generator, device=device)
        predicted = field.render_training(field_origins[batch], field_directions[batch], directions[batch], generator)
        if exposure is not None:
            predicted = exposure(predicted, batch // pixels_per_image)
        colour_loss = torch.mean((predicted - colours[batch]) ** 2)
        loss = colour_loss
        if depth_rays is not None and (config.depth_weight > 0 or config.free_space_weight > 0):
            d_origins, d_directions, d_observed = depth_rays
            d_batch = torch.randint(0, len(d_observed), (config.depth_batch_rays,), generator=generator, device=device)
            observed = d_observed[d_batch]
            free_space_until = observed - config.free_space_margin * field.voxel_size if config.free_space_weight > 0 else None
            expected, in_front = field.render_training_depth(d_origins[d_batch], d_directions[d_batch], generator, free_space_until)
            d_loss = depth_loss(expected, observed)
            if config.depth_weight > 0:
                loss = loss + config.depth_weight * d_loss
            if in_front is not None:
                loss = loss + config.free_space_weight * in_front.mean()
            depth_history.append(float(d_loss.detach()))
        if config.tv_weight > 0:
            loss = loss + config.tv_weight * grid_total_variation(field, config.tv_vertices, generator)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        mse = float(colour_loss.detach())
        smoothed_mse = mse if smoothed_mse is None else 0.95 * smoothed_mse + 0.05 * mse
        bar.update(1)
        if step % 20 == 0:
            bar.set_postfix(
                loss=f"{mse:.5f}", psnr=f"{psnr_from_mse(smoothed_mse):.2f}", **({"depth_rmse": f"{depth_history[-1] ** 0.5:.3f}"} if depth_history else {})
            )
    bar.close()
    field.update_occupancy(config.final_occupancy_alpha)
    seconds = time.monotonic() - start
    info.metadata.update(
        config=config.model_dump(mode="json"),
        steps=step,
        seconds=round(seconds, 1),
        train_psnr=round(psnr_from_mse(smoothed_mse or 1.0), 3),
        resolution=list(field.resolution),
        depth_supervised=depth_rays is not None,
    )
    if depth_history:
        window = min(50, len(depth_history))
        info.metadata.update(
            train_depth_rmse_first=round((sum(depth_history[:window]) / window) ** 0.5, 4),
            train_depth_rmse_last=round((sum(depth_history[-window:]) / window) ** 0.5, 4),
        )
    logger.info("built a grid map in %d steps, %.0f s", step, seconds)
    radiance_map = GridMap(field.eval(), info)
    radiance_map.surface_distance = surface_distance
    return radiance_map


def evaluate_map(render_rays, views: PosedImages, device: torch.device | str = "cpu") -> dict[str, float]:
    """Mean PSNR and SSIM of the map's renders of ``views`` against their images.

    Args:
        render_rays: the map's ``render_rays``.
        views: held-out posed images (same frame as the map).
    Returns:
        ``{"psnr": dB, "ssim": ..., "views": count}``.
    """
    psnrs, ssims = [], []
    for index in range(len(views)):
        pose = views.T_world_cam[index].to(device, torch.float32)
        rendered = render_image(render_rays, pose, views.intrinsics).cpu()
        psnrs.append(psnr(rendered, views.images[index]))
        ssims.append(ssim(rendered, views.images[index]))
    return {"psnr": sum(psnrs) / len(psnrs), "ssim": sum(ssims) / len(ssims), "views": len(psnrs)}


def training_views(poses: torch.Tensor, reference_poses: torch.Tensor) -> torch.Tensor:
    """(N,) bool: the views whose pose (N, 4, 4) is one of the map's reference poses (K, 4, 4), the
    frames it was built from, whatever split, stride or copy of the data set named them.

    A view counts as a training frame when every entry of its camera-to-world matrix is within
    ``TRAINING_POSE_TOLERANCE`` of a reference pose's (the same reader gives the same frame bit
    for bit; distinct frames of a real capture differ far more).
    """
    if not len(poses) or not len(reference_poses):
        return torch.zeros(len(poses), dtype=torch.bool)
    flat, reference = poses[:, :3].reshape(len(poses), 12).double(), reference_poses[:, :3].reshape(len(reference_poses), 12).double()
    return (torch.cdist(flat, reference.to(flat.device), p=float("inf")) <= TRAINING_POSE_TOLERANCE).any(dim=1)


def evaluate_held_out(render_rays, views: PosedImages, reference_poses: torch.Tensor, device: torch.device | str = "cpu") -> dict[str, Any]:
    """:func:`evaluate_map` of the ``views`` the map was not built from, and apart of those it was.

    A score on frames the map trained on says how well it remembers them, not how well it
    predicts new views, so the two are never mixed.

    Args:
        render_rays: the map's ``render_rays``; views: posed images in the map's frame.
        reference_poses: (K, 4, 4) the map's training poses (``reference_poses()``).
    Returns:
        ``{"psnr", "ssim", "views"}`` over the held-out views (``psnr``/``ssim`` None when there is
        none), plus ``"training_frames": {"psnr", "ssim", "views"}`` when some views are training frames.
    """
    trained = training_views(views.T_world_cam, reference_poses)
    held_out = [int(i) for i in torch.nonzero(~trained).flatten()]
    scores: dict[str, Any] = evaluate_map(render_rays, views.subset(held_out), device) if held_out else {"psnr": None, "ssim": None, "views": 0}
    if bool(trained.any()):
        scores["training_frames"] = evaluate_map(render_rays, views.subset([int(i) for i in torch.nonzero(trained).flatten()]), device)
    return scores
