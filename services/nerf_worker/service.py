"""The NeRF worker: a stateless function from update requests to per-particle log-likelihoods."""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from locnerf.field.protocol import RadianceMap, surface_renderer
from locnerf.filter.measurement import particle_log_likelihoods
from locnerf.filter.warp import render_reference, warp_log_likelihoods
from locnerf.geometry.validation import InvalidPoseError, validate_poses
from locnerf.messages.schemas import UpdateRequest, UpdateResult

logger = logging.getLogger(__name__)


class RequestError(ValueError):
    """A request whose content cannot be evaluated (non-rigid poses, pixels outside the image)."""


class NerfWorker:
    """Evaluates update requests against one map.

    Args:
        radiance_map: the map (world or map file) rendering in map units.
        worker_id: name reported in results and in the liveliness token.
    """

    def __init__(self, radiance_map: RadianceMap, worker_id: str) -> None:
        self.map = radiance_map
        self.worker_id = worker_id
        self.render_surface = surface_renderer(radiance_map)
        self._warned_warp = False

    def handle(self, request: UpdateRequest) -> UpdateResult:
        """Log-likelihoods of the request's particles (eq. 5 of the paper, log space).

        Raises:
            RequestError: poses that are not rigid transforms, pixels outside the image.
        """
        started = time.perf_counter()
        device = self.map.device
        poses = torch.tensor(request.poses, dtype=torch.float32).reshape(-1, 4, 4)
        try:
            validate_poses(poses, name="request poses")
        except (InvalidPoseError, ValueError) as error:
            raise RequestError(str(error)) from None
        if request.warp is not None and self.render_surface is not None:
            log_likelihoods = self._warp(request, poses.to(device))
        else:
            if request.warp is not None and not self._warned_warp:
                logger.warning("the map cannot place surfaces (an NDC or MLP map): re-projection requests are rendered from every pose instead")
                self._warned_warp = True
            log_likelihoods = self._render(request, poses.to(device))
        return UpdateResult(
            request_id=request.request_id,
            shard=request.shard,
            worker_id=self.worker_id,
            epoch=request.epoch,
            generation=request.generation,
            ids=request.ids,
            log_likelihoods=log_likelihoods.cpu().tolist(),
            compute_seconds=time.perf_counter() - started,
        )

    def _render(self, request: UpdateRequest, poses: torch.Tensor) -> torch.Tensor:
        """Eq. 5 by rendering the request's pixels from every pose (N, 4, 4) -> (N,)."""
        device = self.map.device
        pixels = torch.tensor(request.pixels, dtype=torch.float32).reshape(-1, 2)
        size = request.intrinsics
        if len(pixels) == 0 or not bool(((pixels >= 0) & (pixels < torch.tensor([size.width, size.height]))).all()):
            raise RequestError(f"request pixels: expected 1 or more (u, v) inside the {size.width}×{size.height} image")
        observed = torch.tensor(request.observed_rgb, dtype=torch.float32).reshape(-1, 3)
        return particle_log_likelihoods(
            poses,
            pixels.to(device),
            observed.to(device),
            request.intrinsics,
            self.map.render_rays,
            request.exponent,
            exposure_gain_range=request.exposure_gain_range,
        )

    def _warp(self, request: UpdateRequest, poses: torch.Tensor) -> torch.Tensor:
        """Eq. 5 by re-projecting the reference render into every pose (N, 4, 4) -> (N,) (:mod:`locnerf.filter.warp`)."""
        warp = request.warp
        size = request.intrinsics
        reference_pose = torch.tensor(warp.reference_pose, dtype=torch.float64)
        try:
            validate_poses(reference_pose, name="warp reference pose")
        except (InvalidPoseError, ValueError) as error:
            raise RequestError(str(error)) from None
        pixels = np.frombuffer(warp.image, dtype=np.uint8).reshape(size.height, size.width, 3)
        image = torch.from_numpy(pixels.copy()).to(self.map.device).float() / 255.0
        reference = render_reference(self.render_surface, reference_pose, size, warp.measurement, torch.Generator().manual_seed(warp.seed))
        return warp_log_likelihoods(poses, reference, image, size, request.exponent, request.exposure_gain_range)
