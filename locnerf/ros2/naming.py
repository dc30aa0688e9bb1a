"""rmw_zenoh key expressions and liveliness tokens (docs/design.md of ros2/rmw_zenoh, Kilted).

Data keys: ``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, the name without its
leading slash, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66…``.

Liveliness tokens (one per node and per publisher, subscription, service server):

``@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node_name>``

``@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/<node_name>/<name>/<type_name>/<type_hash>/<qos>``

where enclave, namespace and name are *mangled* (every ``/`` replaced by ``%``; an empty one is
``%``) and ``<qos>`` is rmw_zenoh's compact QoS string (``qos_to_keyexpr``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from locnerf.messages.codec import DecodeError
from locnerf.ros2.types import dds_type_name, type_hash

ADMIN_SPACE = "@ros2_lv"
DEFAULT_QOS = "::,10:,:,:,,"
"""Reliability, durability and history kind at their defaults, KEEP_LAST depth 10, no deadline,
lifespan or liveliness lease: the form of the design document's examples."""


class EntityKind(str, Enum):
    """The entity kinds of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE_SERVER = "SS"
    SERVICE_CLIENT = "SC"


def fully_qualified_name(name: str, namespace: str = "") -> str:
    """A topic or service name resolved in ``namespace``: ``/ns/name`` (an absolute name is kept).

    Raises:
        ValueError: an empty name, or one with characters that ROS names forbid in a key.
    """
    if not name or any(c in name + namespace for c in "*$?#% "):
        raise ValueError(f"ROS name {name!r} in namespace {namespace!r}: expected a non-empty name without * $ ? # % or spaces")
    if name.startswith("/"):
        return name
    prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{prefix}/{name}"


def normalise_namespace(namespace: str) -> str:
    """A node namespace as ROS writes it: ``robot1``, ``/robot1/`` -> ``/robot1``; ``""`` and ``/`` -> ``""`` (global)."""
    stripped = namespace.strip("/")
    return f"/{stripped}" if stripped else ""


def mangle(name: str) -> str:
    """rmw_zenoh's mangled name: every ``/`` replaced by ``%``; an empty name is ``%``."""
    return name.replace("/", "%") if name else "%"


def data_key(domain_id: int, fq_name: str, ros_type: str) -> str:
    """The key expression of a topic or service: ``<domain>/<name without leading />/<dds type>/<hash>``."""
    if domain_id < 0:
        raise ValueError(f"ROS domain id {domain_id}: expected >= 0")
    return f"{domain_id}/{fq_name.lstrip('/')}/{dds_type_name(ros_type)}/{type_hash(ros_type)}"


def data_pattern(domain_id: int, fq_name: str) -> str:
    """The key expression matching ``fq_name`` with any type name and hash (to count mismatches)."""
    return f"{domain_id}/{fq_name.lstrip('/')}/*/*"


def check_key(key: str, domain_id: int, fq_name: str, ros_type: str) -> None:
    """Raise unless ``key`` is ``fq_name`` in ``domain_id`` with ``ros_type``'s DDS name and type hash.

    Raises:
        DecodeError: ``ros2_key`` (another domain or name), ``ros2_type_name`` or ``ros2_type_hash``,
            naming the received and expected values.
    """
    prefix = f"{domain_id}/{fq_name.lstrip('/')}/"
    if not key.startswith(prefix) or key[len(prefix) :].count("/") != 1:
        raise DecodeError("ros2_key", f"{key}: expected {prefix}<type name>/<type hash>")
    received_name, received_hash = key[len(prefix) :].split("/")
    if received_name != dds_type_name(ros_type):
        raise DecodeError("ros2_type_name", f"{key}: type {received_name!r}, expected {dds_type_name(ros_type)!r}")
    if received_hash != type_hash(ros_type):
        raise DecodeError("ros2_type_hash", f"{key}: type hash {received_hash}, expected {type_hash(ros_type)} for {ros_type}")


@dataclass(frozen=True)
class NodeIdentity:
    """Who a token speaks for: one node of one Zenoh session.

    Attributes:
        domain_id: ROS_DOMAIN_ID.
        session_id: the Zenoh session id, lowercase hex (as ``str(session.info.zid())``).
        node_name: e.g. ``locnerf``.
        namespace: e.g. ``""`` or ``/robot1`` (normalised: ``robot1`` and ``/robot1/`` become ``/robot1``).
        enclave: SROS enclave (``""`` when none).
        node_id: the node's id within the session.
    """

    domain_id: int
    session_id: str
    node_name: str
    namespace: str = ""
    enclave: str = ""
    node_id: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "namespace", normalise_namespace(self.namespace))

    def _prefix(self, entity_id: int, kind: EntityKind) -> str:
        chunks = (ADMIN_SPACE, str(self.domain_id), self.session_id, str(self.node_id), str(entity_id), kind.value)
        return "/".join(chunks + (mangle(self.enclave), mangle(self.namespace), self.node_name))

    def node_token(self) -> str:
        """The node's token (entity id = node id, kind NN)."""
        return self._prefix(self.node_id, EntityKind.NODE)

    def entity_token(self, entity_id: int, kind: EntityKind, fq_name: str, ros_type: str, qos: str = DEFAULT_QOS) -> str:
        """The token of a publisher, subscription or service of this node on ``fq_name``."""
        if kind is EntityKind.NODE:
            raise ValueError("entity_token is for publishers, subscriptions and services; use node_token for the node")
        return "/".join((self._prefix(entity_id, kind), mangle(fq_name), dds_type_name(ros_type), type_hash(ros_type), qos))
