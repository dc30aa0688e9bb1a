"""A ROS 2 service client that queries as rmw_zenoh's does (``rmw_client_data.cpp``, ClientData::make):
a Zenoh querier on the service's key with target ALL_COMPLETE and consolidation NONE. An
ALL_COMPLETE query reaches only queryables declared ``complete``, as rmw_zenoh's servers are."""

from __future__ import annotations

import time

import zenoh

from locnerf_services.transport import TransportConfig
from locnerf_services.transport.bus import Reply
from locnerf_services.transport.zenoh_bus import zenoh_config


class RmwServiceClient:
    """Its own Zenoh session (``transport``), calling services the way ``ros2 service call`` would.

    Args:
        transport: mode and endpoints of the client's session.
    """

    def __init__(self, transport: TransportConfig) -> None:
        self._session = zenoh.open(zenoh_config(transport))

    def call(self, key: str, request: bytes, attachment: bytes, timeout: float) -> list[Reply]:
        """Send the request CDR with its rmw attachment to ``key``; the replies ``(key, payload, attachment)``
        that came within ``timeout`` seconds (rmw_zenoh keeps zenoh's default; a test needs a bound)."""
        querier = self._session.declare_querier(key, target=zenoh.QueryTarget.ALL_COMPLETE, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout)
        try:
            self._wait_for_server(querier, time.monotonic() + timeout)
            replies = []
            for reply in querier.get(payload=request, attachment=attachment):
                if reply.ok is not None:
                    sample = reply.ok
                    replies.append((str(sample.key_expr), sample.payload.to_bytes(), None if sample.attachment is None else sample.attachment.to_bytes()))
            return replies
        finally:
            querier.undeclare()

    @staticmethod
    def _wait_for_server(querier: zenoh.Querier, deadline: float) -> None:
        """Wait until a complete queryable matches the querier, as ``ros2 service call`` waits for the
        service to be available before it sends: a session opened just now has not yet learnt the
        server's declaration, and a query sent before that reaches nobody. Returns at ``deadline``
        (monotonic seconds) in any case; the call then finds no server."""
        while not querier.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)

    def close(self) -> None:
        """Release the session."""
        self._session.close()
