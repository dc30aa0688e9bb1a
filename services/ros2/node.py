"""A ROS 2 node on the Bus, as rmw_zenoh lays it out: liveliness tokens, keys and attachments.

Each publisher, subscription and service server gets an entity id, a liveliness token (so that
``ros2 node list`` / ``ros2 topic list`` would show it) and, for publishers, a GID and a sequence
number for the attachment. rmw_zenoh derives a GID from an XXH3-128 hash of the entity's token;
we take BLAKE2b-128 of the token (the standard library has no XXH3): the GID only has to be unique
and stable per publisher, receivers do not recompute it.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable

from locnerf.messages.codec import DecodeError
from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import (
    EntityKind,
    NodeIdentity,
    data_key,
    data_pattern,
    fully_qualified_name,
)
from locnerf.ros2.types import serialize
from locnerf_services.transport import Bus
from locnerf_services.transport.bus import AttachedCallback, Closeable, Reply

ServiceHandler = Callable[[str, bytes, Attachment | None], bytes | None]


def _gid(token: str) -> bytes:
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


def _now_ns() -> int:
    return time.time_ns()


class Ros2Publisher:
    """Publishes one topic: CDR payload plus the rmw_zenoh attachment (sequence from 1)."""

    def __init__(self, bus: Bus, key: str, ros_type: str, token: str) -> None:
        self.bus, self.key, self.ros_type = bus, key, ros_type
        self.gid = _gid(token)
        self.sequence_number = 0

    def publish(self, message: object) -> None:
        """Serialise ``message`` (a rosbags object of this topic's type) and send it."""
        self.sequence_number += 1
        attachment = Attachment(self.sequence_number, _now_ns(), self.gid).encode()
        self.bus.publish(self.key, serialize(message, self.ros_type), attachment)


class Ros2Node:
    """One ROS 2 node of the session behind ``bus``.

    Args:
        bus: the session (its id goes into the tokens).
        domain_id, node_name, namespace: as ROS names them.
    """

    def __init__(self, bus: Bus, domain_id: int, node_name: str, namespace: str = "") -> None:
        self.bus = bus
        self.identity = NodeIdentity(domain_id=domain_id, session_id=bus.session_id, node_name=node_name, namespace=namespace)
        self.handles: list[Closeable] = [bus.declare_token(self.identity.node_token())]
        self.tokens: list[str] = [self.identity.node_token()]
        self._next_entity = 1

    def resolve(self, name: str) -> str:
        """The fully qualified name of a topic or service name of this node."""
        return fully_qualified_name(name, self.identity.namespace)

    def _declare(self, kind: EntityKind, fq_name: str, ros_type: str) -> str:
        token = self.identity.entity_token(self._next_entity, kind, fq_name, ros_type)
        self._next_entity += 1
        self.handles.append(self.bus.declare_token(token))
        self.tokens.append(token)
        return token

    def publisher(self, name: str, ros_type: str) -> Ros2Publisher:
        """Declare a publisher on ``name``."""
        fq_name = self.resolve(name)
        token = self._declare(EntityKind.PUBLISHER, fq_name, ros_type)
        return Ros2Publisher(self.bus, data_key(self.identity.domain_id, fq_name, ros_type), ros_type, token)

    def subscription(self, name: str, ros_type: str, callback: AttachedCallback) -> str:
        """Subscribe to ``name`` with any type name and hash (the receiver checks them, to count
        mismatches); returns the fully qualified name."""
        fq_name = self.resolve(name)
        self._declare(EntityKind.SUBSCRIPTION, fq_name, ros_type)
        self.handles.append(self.bus.subscribe_attached(data_pattern(self.identity.domain_id, fq_name), callback))
        return fq_name

    def service(self, name: str, service_type: str, handler: ServiceHandler) -> str:
        """Serve ``name``: ``handler(key, request CDR, request attachment or None)`` returns the
        response CDR (None: no reply); the reply's attachment carries the request's sequence number
        and GID, as rmw_zenoh's service server does, so the client can match it. The queryable
        matches any type name and hash so that the handler can count a mismatch, and is declared
        complete as rmw_zenoh's are: its clients query with target ALL_COMPLETE, which reaches no
        other queryable. Returns the fully qualified name."""
        fq_name = self.resolve(name)
        self._declare(EntityKind.SERVICE_SERVER, fq_name, service_type)
        own_gid = _gid(self.tokens[-1])

        def answer(key: str, payload: bytes, attachment: bytes | None) -> list[Reply]:
            try:
                request = Attachment.decode(attachment)
            except DecodeError:
                request = None
            response = handler(key, payload, request)
            if response is None:
                return []
            sequence, gid = (request.sequence_number, request.gid) if request is not None else (0, own_gid)
            return [(key, response, Attachment(sequence, _now_ns(), gid).encode())]

        self.handles.append(self.bus.declare_queryable(data_pattern(self.identity.domain_id, fq_name), answer, complete=True))
        return fq_name

    def close(self) -> None:
        """Undeclare everything (tokens vanish from the graph)."""
        for handle in reversed(self.handles):
            handle.close()
        self.handles.clear()
