"""The NeRF worker: a stateless function from update requests to per-particle log-likelihoods.

Every request gets an answer (:meth:`NerfWorker.answer`): its result, or a refusal naming why
(another map, a request that cannot be evaluated, a computation that failed), so that the filter
acts on it at once instead of waiting for its timeout; a failure never ends the worker.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from locnerf.field.protocol import RadianceMap, surface_distance_of, surface_renderer
from locnerf.filter.depth_measurement import (
    DepthObservation,
    rendered_depth_log_likelihoods,
    surface_distance_log_likelihoods,
    warped_depth_log_likelihoods,
)
from locnerf.filter.final_search import cross_entropy_search
from locnerf.filter.measurement import particle_log_likelihoods
from locnerf.filter.update_likelihood import PoseScore, with_depth
from locnerf.filter.warp import WarpReference, render_reference, warp_log_likelihoods
from locnerf.geometry.validation import InvalidPoseError, validate_poses
from locnerf.maps.source import map_identity
from locnerf.messages.schemas import DepthRequest, RefusalReason, SearchFound, UpdateRefusal, UpdateRequest, UpdateResult
from locnerf_services.rgbd import depth_observation

logger = logging.getLogger(__name__)


class RequestError(ValueError):
    """A request whose content cannot be evaluated (non-rigid poses, pixels outside the image)."""


class WrongMapError(RequestError):
    """A request for another map than the worker's."""


REFUSAL_DETAIL_LENGTH = 1000
"""Characters of an error message kept in a refusal's ``detail``."""


class NerfWorker:
    """Evaluates update requests against one map.

    Args:
        radiance_map: the map (world or map file) rendering in map units; it must have a checksum.
        worker_id: name reported in results and in the liveliness token.

    Raises:
        ValueError: a map without a checksum (:func:`locnerf.maps.source.map_identity`).
    """

    def __init__(self, radiance_map: RadianceMap, worker_id: str) -> None:
        self.map = radiance_map
        self.worker_id = worker_id
        self.map_checksum = map_identity(radiance_map)
        self.failures = 0
        self.render_surface = surface_renderer(radiance_map)
        self.surface_distance = surface_distance_of(radiance_map)
        self._warned_warp = False
        self._warned_depth = False

    def answer(self, request: UpdateRequest) -> UpdateResult | UpdateRefusal:
        """The request's result (:meth:`handle`), or a refusal: ``wrong_map``, ``bad_request`` (a :class:`RequestError`)
        or ``failed`` (any other exception, e.g. out of GPU memory, logged with its traceback the first time)."""
        try:
            return self.handle(request)
        except WrongMapError as error:
            return self._refusal(request, RefusalReason.WRONG_MAP, error)
        except RequestError as error:
            return self._refusal(request, RefusalReason.BAD_REQUEST, error)
        except Exception as error:  # noqa: BLE001 - any failure of the computation is answered, and the worker serves on
            self.failures += 1
            logger.error("request %s shard %d failed: %s: %s", request.request_id, request.shard, type(error).__name__, error, exc_info=self.failures == 1)
            if isinstance(error, torch.cuda.OutOfMemoryError):
                torch.cuda.empty_cache()
            return self._refusal(request, RefusalReason.FAILED, error)

    def _refusal(self, request: UpdateRequest, reason: RefusalReason, error: Exception) -> UpdateRefusal:
        detail = f"{type(error).__name__}: {error}"[:REFUSAL_DETAIL_LENGTH]
        return UpdateRefusal(
            request_id=request.request_id, shard=request.shard, worker_id=self.worker_id, reason=reason, detail=detail, map_checksum=self.map_checksum
        )

    def handle(self, request: UpdateRequest) -> UpdateResult:
        """Log-likelihoods of the request's particles (eq. 5 of the paper, log space), and the result of its search when it carries one.

        Raises:
            WrongMapError: a request for another map (its ``map_checksum`` is not this worker's).
            RequestError: poses that are not rigid transforms, pixels outside the image, a depth part the depth term refuses.
        """
        if request.map_checksum != self.map_checksum:
            raise WrongMapError(f"request for map {request.map_checksum}, this worker holds map {self.map_checksum}")
        started = time.perf_counter()
        device = self.map.device
        poses = torch.tensor(request.poses, dtype=torch.float32).reshape(-1, 4, 4)
        try:
            validate_poses(poses, name="request poses")
        except (InvalidPoseError, ValueError) as error:
            raise RequestError(str(error)) from None
        poses = poses.to(device)
        score, depth_term = self._likelihood(request)
        log_likelihoods = score(poses)
        found = self._search(request, score, depth_term) if request.search is not None else None
        return UpdateResult(
            request_id=request.request_id,
            shard=request.shard,
            worker_id=self.worker_id,
            epoch=request.epoch,
            generation=request.generation,
            ids=request.ids,
            log_likelihoods=log_likelihoods.cpu().tolist(),
            compute_seconds=time.perf_counter() - started,
            search=found,
        )

    def _likelihood(self, request: UpdateRequest) -> tuple[PoseScore, PoseScore | None]:
        """The request's log-likelihood, poses (N, 4, 4) on the map's device -> (N,): the colour term by re-projection
        (a warp request, on a map that places surfaces) or by rendering the request's pixels, plus the depth term of an
        RGB-D request; and that depth term alone (None: colour only). The reference render and the depth image are
        prepared once."""
        depth = self._depth_observation(request.depth) if request.depth is not None else None
        reference = None
        if request.warp is not None and self.render_surface is not None:
            reference = self._reference(request, depth)
            image = self._image(request)

            def colour(poses: torch.Tensor) -> torch.Tensor:
                return warp_log_likelihoods(poses, reference, image, request.intrinsics, request.exponent, request.exposure_gain_range)

        else:
            if request.warp is not None and not self._warned_warp:
                logger.warning("the map cannot place surfaces (an NDC or MLP map): re-projection requests are rendered from every pose instead")
                self._warned_warp = True

            colour = self._rendered_colour(request, request.pixels, request.observed_rgb)

        if request.depth is None or depth is None:
            return colour, None

        def depth_term(poses: torch.Tensor) -> torch.Tensor:
            return self._depth(request.depth, depth, poses, reference)

        return with_depth(colour, depth_term), depth_term

    def _search(self, request: UpdateRequest, score: PoseScore, depth_term: PoseScore | None) -> SearchFound:
        """The request's search (:func:`locnerf.filter.final_search.cross_entropy_search`) on its own likelihood ``score``,
        or, when the search brings its own colour pixels, on those rendered with the request's depth term ``depth_term``."""
        search = request.search
        mean = torch.tensor(search.mean, dtype=torch.float64)
        try:
            validate_poses(mean, name="search mean")
        except (InvalidPoseError, ValueError) as error:
            raise RequestError(str(error)) from None
        if search.pixels is not None:
            score = with_depth(self._rendered_colour(request, search.pixels, search.observed_rgb), depth_term)
        found = cross_entropy_search(
            mean,
            torch.tensor(search.covariance, dtype=torch.float64),
            lambda poses: score(poses.to(self.map.device, torch.float32)).cpu(),
            search.config,
            torch.Generator().manual_seed(search.seed),
        )
        return SearchFound(pose=found.pose.tolist(), log_likelihood=found.log_likelihood, start_log_likelihood=found.start_log_likelihood)

    def _rendered_colour(self, request: UpdateRequest, pixel_list: list[list[float]], observed_list: list[list[float]]) -> PoseScore:
        """Eq. 5 by rendering ``pixel_list`` (M, 2) of the request's image, seen as ``observed_list`` (M, 3), from every
        pose (N, 4, 4) -> (N,); the pixels are checked and moved to the map's device once, not per scoring (a search
        scores its rounds on them)."""
        device = self.map.device
        pixels = torch.tensor(pixel_list, dtype=torch.float32).reshape(-1, 2)
        size = request.intrinsics
        if len(pixels) == 0 or not bool(((pixels >= 0) & (pixels < torch.tensor([size.width, size.height]))).all()):
            raise RequestError(f"request pixels: expected 1 or more (u, v) inside the {size.width}×{size.height} image")
        on_device = pixels.to(device)
        observed = torch.tensor(observed_list, dtype=torch.float32).reshape(-1, 3).to(device)

        def colour(poses: torch.Tensor) -> torch.Tensor:
            return particle_log_likelihoods(
                poses, on_device, observed, request.intrinsics, self.map.render_rays, request.exponent, exposure_gain_range=request.exposure_gain_range
            )

        return colour

    def _image(self, request: UpdateRequest) -> torch.Tensor:
        """The warp request's observed image (H, W, 3) in [0, 1] on the map's device."""
        size = request.intrinsics
        pixels = np.frombuffer(request.warp.image, dtype=np.uint8).reshape(size.height, size.width, 3)
        return torch.from_numpy(pixels.copy()).to(self.map.device).float() / 255.0

    def _reference(self, request: UpdateRequest, depth: DepthObservation | None) -> WarpReference:
        """The reference render of a re-projection request (:mod:`locnerf.filter.warp`): the same on every shard (same pose and seed),
        with depth points inside the view of the request's depth camera (``depth``) when it has one."""
        warp = request.warp
        reference_pose = torch.tensor(warp.reference_pose, dtype=torch.float64)
        try:
            validate_poses(reference_pose, name="warp reference pose")
        except (InvalidPoseError, ValueError) as error:
            raise RequestError(str(error)) from None
        part = request.depth
        rendered_depth = part is not None and part.measurement.depth is not None and part.measurement.depth.likelihood == "rendered"
        depth_pixels = part.measurement.depth.pixels if rendered_depth else 0
        depth_camera, T_cam_depth = (depth.intrinsics, depth.T_cam_depth) if depth is not None else (None, None)
        generator = torch.Generator().manual_seed(warp.seed)
        return render_reference(self.render_surface, reference_pose, request.intrinsics, warp.measurement, generator, depth_pixels, depth_camera, T_cam_depth)

    def _depth_observation(self, depth: DepthRequest) -> DepthObservation:
        """The request's depth image and depth camera in map units, on the map's device (decoded once per request).

        Raises:
            RequestError: a depth image the observation refuses.
        """
        depth_mm = np.frombuffer(depth.image, dtype="<u2").reshape(depth.intrinsics.height, depth.intrinsics.width)
        try:
            return depth_observation(depth_mm, depth.intrinsics, self.map.normalization.scale, self.map.device, depth.T_cam_depth)
        except ValueError as error:
            raise RequestError(f"depth part: {error}") from None

    def _depth(self, depth: DepthRequest, observation: DepthObservation, poses: torch.Tensor, reference: WarpReference | None) -> torch.Tensor:
        """The depth term (N,) of an RGB-D frame for poses (N, 4, 4): the request's depth pixels looked up in the
        map's surface-distance layer when ``likelihood = "surface_distance"`` (a map without one: a bad request);
        otherwise the reference's depth points re-projected when the colour term was, else the request's depth
        pixels rendered from every pose; zeros (colour only, warned once) when the map cannot place surfaces."""
        config = depth.measurement.depth
        pixels = torch.tensor(depth.pixels, dtype=torch.float32).reshape(-1, 2).to(self.map.device)
        if config.likelihood == "surface_distance":
            if self.surface_distance is None:
                raise RequestError(
                    "depth part: likelihood 'surface_distance', but this worker's map has no surface-distance layer (build it from depth images)"
                )
            try:
                return surface_distance_log_likelihoods(poses, observation, pixels, self.surface_distance, config)
            except ValueError as error:
                raise RequestError(f"depth part: {error}") from None
        if self.render_surface is None:
            if not self._warned_depth:
                logger.warning("the map cannot place surfaces (an NDC or MLP map): the depth term of RGB-D requests is left out")
                self._warned_depth = True
            return torch.zeros(poses.shape[0], dtype=torch.float32, device=poses.device)
        try:
            if reference is not None:
                return warped_depth_log_likelihoods(poses, reference.depth_points, observation, config)
            return rendered_depth_log_likelihoods(poses, observation, pixels, self.render_surface, config, depth.measurement.ray_chunk)
        except ValueError as error:  # a depth part the measurement refuses is a bad request, not a reason to stop
            raise RequestError(f"depth part: {error}") from None
