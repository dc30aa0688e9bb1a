"""Transport configuration: embedded peer-to-peer on loopback by default, a router for compose.

Environment overrides (used by docker compose and ``locnerf up``): ``LOCNERF_ZENOH_MODE``
(peer | client), ``LOCNERF_ZENOH_CONNECT`` and ``LOCNERF_ZENOH_LISTEN`` (comma-separated
endpoints such as ``tcp/127.0.0.1:7447``).
"""

from __future__ import annotations

import os
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

ENV_MODE = "LOCNERF_ZENOH_MODE"
ENV_CONNECT = "LOCNERF_ZENOH_CONNECT"
ENV_LISTEN = "LOCNERF_ZENOH_LISTEN"


class TransportConfig(BaseModel):
    """How a service opens its Zenoh session."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: Literal["peer", "client"] = Field("peer", description="Zenoh mode: peer (embedded default) or client (of a zenohd router).")
    connect: tuple[str, ...] = Field((), description="Endpoints to connect to, e.g. tcp/127.0.0.1:7447 or tcp/zenohd:7447.")
    listen: tuple[str, ...] = Field(
        ("tcp/127.0.0.1:0",), description="Endpoints to listen on (peer mode); port 0 picks a free port, advertised by gossip."
    )
    multicast_scouting: bool = Field(False, description="UDP multicast discovery (off: endpoints are explicit).")
    block_when_congested: bool = Field(
        False,
        description="Publishers wait when the network queue is full instead of dropping (the services drop: a stale sample "
        "is worth less than a blocked pose thread; locnerf fuzz blocks, so that every payload it counts is delivered).",
    )

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for endpoint in value:
            if "/" not in endpoint:
                raise ValueError(f"endpoint {endpoint!r}: expected <protocol>/<address>, e.g. tcp/127.0.0.1:7447")
        return value

    def with_environment(self, environ: dict[str, str] | None = None) -> "TransportConfig":
        """This config with the ``LOCNERF_ZENOH_*`` variables applied."""
        environ = os.environ if environ is None else environ
        updates: dict[str, object] = {}
        if environ.get(ENV_MODE):
            updates["mode"] = environ[ENV_MODE]
        for name, field in ((ENV_CONNECT, "connect"), (ENV_LISTEN, "listen")):
            if name in environ:
                updates[field] = tuple(e.strip() for e in environ[name].split(",") if e.strip())
        return TransportConfig.model_validate(self.model_dump() | updates)
