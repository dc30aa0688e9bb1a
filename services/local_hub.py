"""A hub for service processes on one machine: a listening Zenoh session and their supervisor.

The hub session listens on ``tcp/127.0.0.1:<port>``; the supervised services connect to it in peer
mode (and then find one another by gossip). Closing the hub stops the services first, then its
subscriptions and its session, so that nothing the services send at the end meets a closed session.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

from locnerf_services.supervisor import STOP_TIMEOUT_S, Supervisor, free_port, loopback_environment
from locnerf_services.transport import TransportConfig, open_bus
from locnerf_services.transport.bus import Bus, Closeable, SampleCallback


class LocalHub:
    """A listening session (``bus``) and a :class:`Supervisor` (``supervisor``) whose processes join it.

    Args:
        logs: the supervisor's folder for logs and configs.
        port: loopback port to listen on (0: a free one).
        transport: settings of the hub session; its ``listen`` is replaced by the hub's endpoint.
        stop_timeout: seconds between SIGTERM and SIGKILL when stopping the services.
        environment: base environment of the services (default: this process's).
        cwd: working directory of the services.
    """

    def __init__(
        self,
        logs: Path,
        port: int = 0,
        transport: TransportConfig | None = None,
        stop_timeout: float = STOP_TIMEOUT_S,
        environment: Mapping[str, str] | None = None,
        cwd: Path | None = None,
    ) -> None:
        if not 0 <= port < 65536:
            raise ValueError(f"port {port}: expected 0 (a free one) to 65535")
        self.endpoint = f"tcp/127.0.0.1:{port or free_port()}"
        settings = (transport or TransportConfig()).model_dump() | {"listen": (self.endpoint,)}
        self.bus: Bus = open_bus(TransportConfig.model_validate(settings))
        self.supervisor = Supervisor(logs, loopback_environment(self.endpoint, environment), stop_timeout, cwd)
        self._subscriptions: list[Closeable] = []

    def subscribe(self, key_expr: str, callback: SampleCallback) -> Closeable:
        """``bus.subscribe``, closed with the hub."""
        subscription = self.bus.subscribe(key_expr, callback)
        self._subscriptions.append(subscription)
        return subscription

    def close(self) -> dict[str, int]:
        """Stop the services, close the subscriptions and the session; the services' exit codes by name."""
        try:
            return self.supervisor.stop_all()
        finally:
            for subscription in self._subscriptions:
                subscription.close()
            self._subscriptions.clear()
            self.bus.close()

    def __enter__(self) -> LocalHub:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None) -> None:
        self.close()
