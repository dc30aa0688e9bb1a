"""How well the training images can explain held-out RGB-D views at all: the re-projection ceiling of a map.

A map is fitted to its training images, so where a held-out view sees a surface, the best colour a
map can give it is about what the training frames recorded there. For each held-out view, its own
depth image becomes world points (the view's measured geometry: no map involved); each point is
projected into the ``candidates`` training frames nearest in position and viewing direction and kept
where that frame's depth image reads the point's depth (:func:`seen_in_depth`); the mean of those
frames' colours is the **re-projected** colour, and the point is **covered**. Compared with the
held-out view's own colour at the point:

- ``ceiling_psnr``: PSNR of the re-projected colours on covered points: what a perfect map of the
  training images could score there, with a perfect geometry and the training images' own sharpness;
- ``ceiling_psnr_colour_fitted``: the same after the least-squares affine colour transform (3×4) of
  the view, a diagnostic of how much of the rest is exposure and white balance (fitted on the
  points it scores, so an upper bound);
- ``map_psnr_covered`` / ``map_psnr_uncovered``: the map's render at the view's pose, read at the
  same points, where the training frames saw them and where they did not;
- ``map_psnr_without_depth``: the map on the colour pixels that no depth point of the view falls on
  (the colour camera's wider field of view, holes): nothing tells what the view saw there;
- ``coverage``: covered points over the view's depth points inside its colour image;
  ``pixels_with_depth``: the share of colour pixels some depth point falls on; ``map_psnr``: the
  map's whole-image PSNR, as ``map eval`` gives it.

Views without depth points in their image are skipped. Means are over views (as ``map eval``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from locnerf.data.depth_visibility import project_world_points, seen_in_depth
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import depth_points
from locnerf.errors import DatasetError
from locnerf.filter.warp import sample_image
from locnerf.render.image import RenderRays, render_image
from locnerf.train.metrics import psnr, psnr_from_mse

SUMMARY_KEYS = (
    "coverage",
    "pixels_with_depth",
    "ceiling_psnr",
    "ceiling_psnr_colour_fitted",
    "map_psnr_covered",
    "map_psnr_uncovered",
    "map_psnr_without_depth",
    "map_psnr",
)


@dataclass(frozen=True)
class CeilingConfig:
    """How training frames are chosen for a held-out view and when one of them saw a point.

    Attributes:
        candidates: training frames tried per view, the nearest by ``‖c − c_j‖ + direction_weight · (1 − a·a_j)``
            (camera centres c, optical axes a).
        direction_weight: map units that one unit of ``1 − cos`` between optical axes counts as.
        depth_tolerance: a training frame saw a point where its depth reading is within this fraction of the point's depth.
    """

    candidates: int = 30
    direction_weight: float = 0.5
    depth_tolerance: float = 0.04


def _psnr(predicted: torch.Tensor, target: torch.Tensor) -> float | None:
    """PSNR (dB) of colours (P, 3) against (P, 3); None for no points."""
    if len(target) == 0:
        return None
    return psnr_from_mse(float(((predicted - target) ** 2).mean()))


def _colour_fitted(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``predicted`` (P, 3) through the least-squares affine colour transform onto ``target`` (P, 3)."""
    design = torch.cat((predicted, torch.ones_like(predicted[:, :1])), dim=-1)
    return design @ torch.linalg.lstsq(design, target).solution


def _nearest_training_frames(training: PosedImages, pose: torch.Tensor, config: CeilingConfig) -> list[int]:
    """Positions of the ``config.candidates`` training frames nearest to ``pose`` (4, 4) in position and viewing direction."""
    poses = training.T_world_cam.double()
    score = (poses[:, :3, 3] - pose[:3, 3]).norm(dim=-1) + config.direction_weight * (1.0 - poses[:, :3, 2] @ pose[:3, 2])
    return score.argsort()[: config.candidates].tolist()


def view_ceiling(view: PosedImages, position: int, training: PosedImages, render_rays: RenderRays, config: CeilingConfig) -> dict[str, float | None] | None:
    """The figures of the module docstring for one held-out view (None when no depth point falls in its image).

    Args:
        view: held-out frames with depth, on the map's camera (``on_map_camera``).
        position: which of them.
        training: the map's training frames with depth, on the same camera.
        render_rays: the map's ``render_rays``.
    """
    pose = view.T_world_cam[position].double()
    points = depth_points(view.depths[position : position + 1], view.depth_poses()[position : position + 1], view.depth_intrinsics)
    points = torch.cat((points, torch.ones_like(points[:, :1])), dim=-1)
    pixels, _, inside = project_world_points(points, pose, view.intrinsics)
    points, pixels = points[inside], pixels[inside][None]
    if len(points) == 0:
        return None
    everywhere = torch.ones(1, len(points), dtype=torch.bool)
    observed = sample_image(view.images[position].double(), pixels, everywhere)[0]
    rendering = render_image(render_rays, pose.float(), view.intrinsics).cpu()
    rendered = sample_image(rendering.double(), pixels, everywhere)[0]
    total, seen = torch.zeros_like(observed), torch.zeros(len(points), dtype=torch.float64)
    for frame in _nearest_training_frames(training, pose, config):
        in_colour = project_world_points(points, training.T_world_cam[frame].double(), training.intrinsics)
        visible = seen_in_depth(training, frame, points, config.depth_tolerance) & in_colour[2]
        colours = sample_image(training.images[frame].double(), in_colour[0][None], visible[None])[0]
        total += colours * visible[:, None]
        seen += visible
    covered = seen > 0
    reprojected = total[covered] / seen[covered, None]
    fitted = _colour_fitted(reprojected, observed[covered]) if int(covered.sum()) >= 4 else reprojected
    width = view.intrinsics.width
    hit = torch.zeros(view.intrinsics.height * width, dtype=torch.bool)
    hit[(pixels[0, :, 1].round().long() * width + pixels[0, :, 0].round().long())] = True
    without_depth = rendering.reshape(-1, 3)[~hit].double(), view.images[position].reshape(-1, 3)[~hit].double()
    return {
        "coverage": float(covered.double().mean()),
        "pixels_with_depth": float(hit.double().mean()),
        "ceiling_psnr": _psnr(reprojected, observed[covered]),
        "ceiling_psnr_colour_fitted": _psnr(fitted, observed[covered]),
        "map_psnr_covered": _psnr(rendered[covered], observed[covered]),
        "map_psnr_uncovered": _psnr(rendered[~covered], observed[~covered]),
        "map_psnr_without_depth": _psnr(*without_depth),
        "map_psnr": psnr(rendering, view.images[position]),
    }


def reprojection_ceiling(views: PosedImages, training: PosedImages, render_rays: RenderRays, config: CeilingConfig | None = None) -> dict[str, object]:
    """Per-view figures (:func:`view_ceiling`) and their means over the views that have them.

    Returns:
        ``{"views": [{"name", ...figures}], "summary": {figure: mean or None, "views": count}}``.
    Raises:
        DatasetError: if either set has no depth images.
    """
    config = config or CeilingConfig()
    for name, images in (("held-out views", views), ("training frames", training)):
        if images.depths is None or images.depth_intrinsics is None:
            raise DatasetError(f"{images.source}: the re-projection ceiling needs depth images in the {name}")
    rows = []
    for position in range(len(views)):
        figures = view_ceiling(views, position, training, render_rays, config)
        if figures is not None:
            rows.append({"name": views.names[position], **figures})
    summary: dict[str, float | int | None] = {"views": len(rows)}
    for key in SUMMARY_KEYS:
        values = [row[key] for row in rows if row[key] is not None and math.isfinite(row[key])]
        summary[key] = sum(values) / len(values) if values else None
    return {"views": rows, "summary": summary}
