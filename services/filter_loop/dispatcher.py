"""Sharding updates over the live workers: send, retry on a vanished or failing worker, give up on timeout.

Up to ``max_in_flight`` updates run at once (so a worker has the next request queued while the
filter merges the previous one). Only workers whose liveliness token announces the filter's map
(its checksum) are used; the others are counted, logged once each and listed. Each update's
particles are split into one shard per live worker; a shard whose worker's liveliness token
disappears, or whose worker refuses it as ``failed`` or ``wrong_map``, is sent again to another live
worker (one it has not been sent to, while there is one; or to the next one that appears), at most
``max_shard_attempts`` sends in all, after which the update is given up. A shard refused as
``bad_request`` gives the update up at once (every worker would refuse it). When every shard has
answered, the results are joined for the merge. An update that is not complete after ``timeout``
seconds is abandoned and counted.
"""

from __future__ import annotations

import collections
import itertools
import logging
import uuid
from dataclasses import dataclass, field

import torch

from locnerf.filter.cloud_search import PoseSearch
from locnerf.filter.localizer import UpdateSnapshot
from locnerf.messages.keys import WorkerToken
from locnerf.messages.schemas import (
    DepthRequest,
    RefusalReason,
    SearchFound,
    SearchRequest,
    UpdateRefusal,
    UpdateRequest,
    UpdateResult,
    WarpRequest,
)
from locnerf.render.camera import PinholeIntrinsics

logger = logging.getLogger(__name__)


@dataclass
class _Shard:
    request: UpdateRequest
    worker: str | None
    tried: list[str] = field(default_factory=list)  # the workers it was sent to, in order
    log_likelihoods: list[float] | None = None
    found: SearchFound | None = None


@dataclass
class _Update:
    request_id: str
    snapshot: UpdateSnapshot
    started: float
    image: torch.Tensor | None
    search: PoseSearch | None = None
    shards: list[_Shard] = field(default_factory=list)

    def complete(self) -> bool:
        return all(shard.log_likelihoods is not None for shard in self.shards)


@dataclass(frozen=True)
class CompletedUpdate:
    """Joined results: ``ids`` (N,) and ``log_likelihoods`` (N,) of snapshot ``(epoch, generation)``,
    with the update's ``image`` (H, W, 3) if one was kept, its camera, whether it was a re-projection,
    and the search it carried with what the search found (both None without one)."""

    epoch: int
    generation: int
    ids: torch.Tensor
    log_likelihoods: torch.Tensor
    latency: float
    image: torch.Tensor | None
    intrinsics: PinholeIntrinsics
    warped: bool = False
    search: PoseSearch | None = None
    found: SearchFound | None = None


AddressedRequest = tuple[str, UpdateRequest]
"""An update request shard and the id of the worker it goes to: (worker_id, request)."""

ISSUED_MEMORY = 4096
"""Request ids remembered after their update ended, to tell a late result from a forged one."""


class UnknownRequestError(ValueError):
    """A result for a request id this filter never issued (or so long ago that it was forgotten)."""


class UpdateDispatcher:
    """Tracks live workers and the update in flight.

    Args:
        map_checksum: identity of the filter's map; workers announcing another are not used.
        timeout: seconds after which an incomplete update is abandoned.
        max_in_flight: updates allowed in flight at once.
        max_shard_attempts: sends of one shard (to a worker that then vanished or refused it) before its update is given up.
    """

    def __init__(self, map_checksum: str, timeout: float, max_in_flight: int = 2, max_shard_attempts: int = 3) -> None:
        if max_in_flight < 1:
            raise ValueError(f"max_in_flight {max_in_flight}: expected >= 1")
        if max_shard_attempts < 1:
            raise ValueError(f"max_shard_attempts {max_shard_attempts}: expected >= 1")
        self.map_checksum = map_checksum
        self.timeout = timeout
        self.max_in_flight = max_in_flight
        self.max_shard_attempts = max_shard_attempts
        self.workers: dict[str, str] = {}
        self.other_map: dict[str, str] = {}  # live workers holding another map -> their map's checksum
        self._warned_other_map: set[str] = set()
        self.pending: dict[str, _Update] = {}
        self.counters: collections.Counter[str] = collections.Counter()
        self._turn = itertools.count()
        self._issued: collections.deque[str] = collections.deque(maxlen=ISSUED_MEMORY)
        self._issued_set: set[str] = set()

    @property
    def can_start(self) -> bool:
        """A worker is alive and fewer than ``max_in_flight`` updates are pending."""
        return bool(self.workers) and len(self.pending) < self.max_in_flight

    @property
    def in_flight(self) -> int:
        """Shards sent and not answered."""
        return sum(s.log_likelihoods is None for update in self.pending.values() for s in update.shards)

    def _next_worker(self, tried: list[str]) -> str | None:
        """A live worker, in turn among those not in ``tried`` while there are any; None when none is live."""
        untried = sorted(name for name in self.workers if name not in tried)
        names = untried or sorted(self.workers)
        if not names:
            return None
        return names[next(self._turn) % len(names)]

    def worker_changed(self, token: WorkerToken, alive: bool) -> list[AddressedRequest]:
        """Record a liveliness change; returns shards re-sent because of it. A token announcing another map
        than the filter's is counted (``workers_on_another_map``) and listed in :attr:`other_map`, and its worker is not used."""
        if token.map_checksum != self.map_checksum:
            if alive:
                self._note_other_map(token.worker_id, token.map_checksum)
            else:
                self.other_map.pop(token.worker_id, None)
            return []
        if alive:
            self.workers[token.worker_id] = token.device
        else:
            self.workers.pop(token.worker_id, None)
        resend = []
        for update in list(self.pending.values()):
            for shard in update.shards:
                if update.request_id not in self.pending:
                    break
                if shard.log_likelihoods is None and (shard.worker is None or shard.worker not in self.workers):
                    resend += self._resend(update, shard)
        return resend

    def _note_other_map(self, worker_id: str, map_checksum: str) -> None:
        """Leave ``worker_id`` out: it holds map ``map_checksum`` (logged once per worker)."""
        self.workers.pop(worker_id, None)
        self.other_map[worker_id] = map_checksum
        self.counters["workers_on_another_map"] += 1
        if worker_id not in self._warned_other_map:
            self._warned_other_map.add(worker_id)
            logger.warning("worker %s holds map %s, not the filter's map %s: it is left out", worker_id, map_checksum, self.map_checksum)

    def _resend(self, update: _Update, shard: _Shard) -> list[AddressedRequest]:
        """Send ``shard`` again to another live worker: [(worker, request)], or [] when none is live (the shard waits
        for the next one) or when it was sent ``max_shard_attempts`` times already (then ``update`` is given up)."""
        if len(shard.tried) >= self.max_shard_attempts:
            self._give_up(update, f"shard {shard.request.shard} was sent {len(shard.tried)} times ({', '.join(shard.tried)}) without a result")
            return []
        shard.worker = self._next_worker(shard.tried)
        if shard.worker is None:
            return []
        shard.tried.append(shard.worker)
        self.counters["shards_retried"] += 1
        logger.info("re-sending shard %d of update %s to %s", shard.request.shard, update.request_id, shard.worker)
        return [(shard.worker, shard.request)]

    def _give_up(self, update: _Update, why: str) -> None:
        del self.pending[update.request_id]
        self.counters["updates_given_up"] += 1
        logger.warning("giving up update %s: %s", update.request_id, why)

    def start(
        self,
        snapshot: UpdateSnapshot,
        pixels: torch.Tensor,
        observed_rgb: torch.Tensor,
        intrinsics: PinholeIntrinsics,
        exponent: float,
        now: float,
        image: torch.Tensor | None = None,
        exposure_gain_range: tuple[float, float] | None = None,
        warp: WarpRequest | None = None,
        depth: DepthRequest | None = None,
        search: PoseSearch | None = None,
    ) -> list[AddressedRequest]:
        """Split ``snapshot`` over the live workers; pixels (M, 2), observed_rgb (M, 3); ``image``
        (H, W, 3) is kept until the update completes (for kidnapping recovery); ``exposure_gain_range``
        asks the workers for the exposure-invariant likelihood (None: off); ``warp`` for re-projection,
        ``depth`` for the depth term of an RGB-D frame (every shard gets the same of both); ``search``
        goes with shard 0 only.

        Raises:
            RuntimeError: if :attr:`can_start` is false.
        """
        if not self.can_start:
            raise RuntimeError(f"cannot start an update: {len(self.pending)} in flight (max {self.max_in_flight}), {len(self.workers)} worker(s)")
        names = sorted(self.workers)
        update = _Update(uuid.uuid4().hex[:12], snapshot, now, image, search)
        searching = None
        if search is not None:
            searching = SearchRequest(
                mean=search.mean.tolist(),
                covariance=search.covariance.tolist(),
                config=search.config,
                seed=search.seed,
                pixels=search.pixels.tolist() if search.pixels is not None else None,
                observed_rgb=search.observed.tolist() if search.observed is not None else None,
            )
        poses = snapshot.poses.detach().double().cpu().reshape(-1, 16)
        ids = snapshot.ids.cpu()
        common = {
            "request_id": update.request_id,
            "map_checksum": self.map_checksum,
            "epoch": snapshot.epoch,
            "generation": snapshot.generation,
            "pixels": pixels.cpu().tolist(),
            "observed_rgb": observed_rgb.cpu().tolist(),
            "intrinsics": intrinsics,
            "exponent": exponent,
            "exposure_gain_range": exposure_gain_range,
            "warp": warp,
            "depth": depth,
        }
        parts = torch.tensor_split(torch.arange(len(ids)), min(len(names), len(ids)))
        for index, (part, worker) in enumerate(zip(parts, names)):
            request = UpdateRequest(shard=index, ids=ids[part].tolist(), poses=poses[part].tolist(), search=searching if index == 0 else None, **common)
            update.shards.append(_Shard(request, worker, [worker]))
        self.pending[update.request_id] = update
        if len(self._issued) == self._issued.maxlen:
            self._issued_set.discard(self._issued[0])
        self._issued.append(update.request_id)
        self._issued_set.add(update.request_id)
        self.counters["updates_started"] += 1
        if warp is not None:
            self.counters["updates_warped"] += 1
        if depth is not None:
            self.counters["updates_with_depth"] += 1
        if search is not None:
            self.counters["updates_with_search"] += 1
        return [(shard.worker, shard.request) for shard in update.shards]

    def receive(self, result: UpdateResult, now: float) -> CompletedUpdate | None:
        """Store a shard's result; the joined update once every shard has answered.

        Raises:
            UnknownRequestError: a result for a request id never issued (or forgotten, see ``ISSUED_MEMORY``).
            ValueError: a result for the pending update whose ids do not match its shard.
        """
        update = self.pending.get(result.request_id)
        if update is None:
            if result.request_id not in self._issued_set:
                raise UnknownRequestError(f"result from {result.worker_id} for request {result.request_id!r}, which this filter never issued")
            self.counters["late_results"] += 1
            return None
        if result.shard >= len(update.shards) or result.ids != update.shards[result.shard].request.ids:
            raise ValueError(f"result of shard {result.shard} from {result.worker_id}: no such shard, or particle ids differ from the request's")
        shard = update.shards[result.shard]
        if (result.search is None) != (shard.request.search is None):
            raise ValueError(f"result of shard {result.shard} from {result.worker_id}: a search result without a search, or none for the one asked")
        shard.log_likelihoods = result.log_likelihoods
        shard.found = result.search
        if not update.complete():
            return None
        del self.pending[update.request_id]
        return CompletedUpdate(
            epoch=update.snapshot.epoch,
            generation=update.snapshot.generation,
            ids=torch.tensor([i for s in update.shards for i in s.request.ids], dtype=torch.int64),
            log_likelihoods=torch.tensor([x for s in update.shards for x in s.log_likelihoods], dtype=torch.float64),
            latency=now - update.started,
            image=update.image,
            intrinsics=update.shards[0].request.intrinsics,
            warped=update.shards[0].request.warp is not None,
            search=update.search,
            found=update.shards[0].found,
        )

    def refused(self, refusal: UpdateRefusal) -> list[AddressedRequest]:
        """Act on a worker's refusal at once: the shard re-sent elsewhere (``failed``, ``wrong_map``, whose worker is
        then left out as on another map) or the update given up (``bad_request``, or a shard out of attempts);
        returns the shards re-sent. A refusal of a shard already answered or sent elsewhere is counted as late.

        Raises:
            UnknownRequestError: a refusal for a request id never issued (or forgotten, see ``ISSUED_MEMORY``).
            ValueError: a refusal of a shard the pending update does not have.
        """
        update = self.pending.get(refusal.request_id)
        if update is None:
            if refusal.request_id not in self._issued_set:
                raise UnknownRequestError(f"refusal from {refusal.worker_id} for request {refusal.request_id!r}, which this filter never issued")
            self.counters["late_results"] += 1
            return []
        if refusal.shard >= len(update.shards):
            raise ValueError(f"refusal of shard {refusal.shard} from {refusal.worker_id}: update {refusal.request_id} has {len(update.shards)} shards")
        shard = update.shards[refusal.shard]
        if shard.log_likelihoods is not None or shard.worker != refusal.worker_id:
            self.counters["late_results"] += 1
            return []
        self.counters[f"shards_refused_{refusal.reason.value}"] += 1
        logger.warning("worker %s refused shard %d of update %s (%s): %s", refusal.worker_id, refusal.shard, update.request_id, refusal.reason, refusal.detail)
        if refusal.reason is RefusalReason.BAD_REQUEST:
            self._give_up(update, f"worker {refusal.worker_id} refused shard {refusal.shard} as a bad request")
            return []
        if refusal.reason is RefusalReason.WRONG_MAP:
            self._note_other_map(refusal.worker_id, refusal.map_checksum)
        return self._resend(update, shard)

    def expire(self, now: float) -> int:
        """Abandon the updates older than ``timeout``; returns how many."""
        expired = [update for update in self.pending.values() if now - update.started > self.timeout]
        for update in expired:
            unanswered = sum(s.log_likelihoods is None for s in update.shards)
            logger.warning("update %s timed out after %.1f s with %d shard(s) unanswered", update.request_id, now - update.started, unanswered)
            del self.pending[update.request_id]
            self.counters["updates_timed_out"] += 1
        return len(expired)
