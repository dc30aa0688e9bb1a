"""Transport: the Bus protocol, its Zenoh implementation and an in-memory one for tests."""

from __future__ import annotations

from services.transport.bus import Bus, Inbox, LatestSlot
from services.transport.config import TransportConfig


def open_bus(config: TransportConfig) -> Bus:
    """A Zenoh bus for ``config`` (imports zenoh only when called)."""
    from services.transport.zenoh_bus import ZenohBus

    return ZenohBus(config)


__all__ = ["Bus", "Inbox", "LatestSlot", "TransportConfig", "open_bus"]
