"""What ``locnerf view`` reads from the bus: the filter's poses, particles and status, ground truth, camera images.

Zenoh callbacks only enqueue the raw payloads; :meth:`ViewFeed.next` and :meth:`ViewFeed.take_image`
decode them (with :mod:`locnerf.messages.codec`) on the caller's thread. Images go to a slot that
keeps only the newest, since the view shows them at a low rate; everything else to a FIFO.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
from pydantic import BaseModel

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode, decode_image
from locnerf.messages.schemas import FilterStatus, ImageHeader, ParticleCloud, PoseEstimate, PoseStamped
from locnerf_services.transport import Bus, Inbox, LatestSlot

logger = logging.getLogger(__name__)

Kind = Literal["pose", "truth", "particles", "status"]
MESSAGES: dict[Kind, tuple[keys.Topic, type[BaseModel]]] = {
    "pose": (keys.POSE, PoseEstimate),
    "truth": (keys.GROUND_TRUTH, PoseStamped),
    "particles": (keys.PARTICLES, ParticleCloud),
    "status": (keys.STATUS, FilterStatus),
}
MAX_IMAGE_PIXELS = 4096 * 4096
"""Larger image headers are refused as bad messages rather than allocated."""


class ViewFeed:
    """Subscriptions of one robot's topics on ``bus``; ``bad_messages`` counts payloads that did not decode.

    Args:
        bus: an open session (closed by the caller after :meth:`close`).
        robot_id: the robot whose keys (``locnerf/<robot_id>/...``) are read.
        capacity: messages held before the oldest is dropped.
    """

    def __init__(self, bus: Bus, robot_id: str, capacity: int = 4096) -> None:
        self._inbox: Inbox[tuple[Kind, bytes]] = Inbox(capacity)
        self._image: LatestSlot[bytes] = LatestSlot()
        self.bad_messages = 0
        self._handles = [
            bus.subscribe(keys.key(robot_id, topic), lambda _k, payload, kind=kind: self._inbox.put((kind, payload))) for kind, (topic, _) in MESSAGES.items()
        ]
        self._handles.append(bus.subscribe(keys.key(robot_id, keys.IMAGE), lambda _k, payload: self._image.put(payload)))

    def _bad(self, what: str, error: DecodeError) -> None:
        self.bad_messages += 1
        logger.warning("bad %s message (%d so far): %s", what, self.bad_messages, error)

    def next(self, timeout: float) -> tuple[Kind, BaseModel] | None:
        """The oldest message as (kind, decoded message), waiting up to ``timeout`` s; None if none arrived
        (or it did not decode: then it is counted and logged)."""
        item = self._inbox.get(timeout)
        if item is None:
            return None
        kind, payload = item
        try:
            return kind, decode(payload, MESSAGES[kind][1])
        except DecodeError as error:
            self._bad(kind, error)
            return None

    def take_image(self) -> tuple[ImageHeader, np.ndarray] | None:
        """The newest camera frame since the last call as (header, pixels (H, W, 3) uint8 RGB), or None."""
        payload = self._image.take()
        if payload is None:
            return None
        try:
            return decode_image(payload, max_pixels=MAX_IMAGE_PIXELS)
        except DecodeError as error:
            self._bad("image", error)
            return None

    @property
    def dropped(self) -> int:
        """Messages dropped because the view fell behind."""
        return self._inbox.dropped

    def close(self) -> None:
        """Undeclare the subscriptions."""
        for handle in self._handles:
            handle.close()
