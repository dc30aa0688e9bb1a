"""Transport: the Bus protocol, its Zenoh implementation and an in-memory one for tests."""

from __future__ import annotations

from locnerf_services.transport.bus import Bus, Inbox, LatestSlot
from locnerf_services.transport.config import TransportConfig


def open_bus(config: TransportConfig) -> Bus:
    """A Zenoh bus for ``config`` (imports zenoh only when called)."""
    from locnerf_services.transport.zenoh_bus import ZenohBus

    return ZenohBus(config)


__all__ = ["Bus", "Inbox", "LatestSlot", "TransportConfig", "open_bus"]
