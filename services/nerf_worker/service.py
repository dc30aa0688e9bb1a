"""The NeRF worker: a stateless function from update requests to per-particle log-likelihoods."""

from __future__ import annotations

import time

import torch

from locnerf.field.protocol import RadianceMap
from locnerf.filter.measurement import particle_log_likelihoods
from locnerf.geometry.validation import InvalidPoseError, validate_poses
from locnerf.messages.schemas import UpdateRequest, UpdateResult


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
        pixels = torch.tensor(request.pixels, dtype=torch.float32).reshape(-1, 2)
        size = request.intrinsics
        if len(pixels) == 0 or not bool(((pixels >= 0) & (pixels < torch.tensor([size.width, size.height]))).all()):
            raise RequestError(f"request pixels: expected 1 or more (u, v) inside the {size.width}×{size.height} image")
        observed = torch.tensor(request.observed_rgb, dtype=torch.float32).reshape(-1, 3)
        log_likelihoods = particle_log_likelihoods(
            poses.to(device),
            pixels.to(device),
            observed.to(device),
            request.intrinsics,
            self.map.render_rays,
            request.exponent,
            exposure_gain_range=request.exposure_gain_range,
        )
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
