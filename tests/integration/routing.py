"""A router process for the integration tests (``locnerf run router``) and clients of it."""

from __future__ import annotations

import json
import time
from pathlib import Path

from locnerf_services.transport import TransportConfig, open_bus
from locnerf_services.transport.config import ENV_TLS, TlsConfig
from tests.integration.conftest import REPO, Stack

PLAIN = REPO / "deploy/zenoh/router.json5"
SECURE = REPO / "deploy/zenoh/router-tls.json5"


def start_router(stack: Stack, name: str, endpoint: str, certs: Path | None = None) -> None:
    """``locnerf run router`` listening on ``endpoint``: the plain compose file, or with ``certs``
    the TLS and access-control file with its certificate paths pointed at ``certs``."""
    overrides = {"listen/endpoints": [endpoint]}
    if certs is not None:
        overrides |= {
            "transport/link/tls/root_ca_certificate": str(certs / "ca.pem"),
            "transport/link/tls/listen_certificate": str(certs / "router.pem"),
            "transport/link/tls/listen_private_key": str(certs / "router-key.pem"),
        }
    arguments = ["--config", str(SECURE if certs is not None else PLAIN)]
    for key, value in overrides.items():
        arguments += ["--cfg", f"{key}:{json.dumps(value)}"]
    stack.start(name, "run", "router", *arguments)


def tls_for(certs: Path, role: str) -> TlsConfig:
    """Mutual TLS with the certificate of ``role`` (its CN)."""
    return TlsConfig(root_ca=str(certs / "ca.pem"), certificate=str(certs / f"{role}.pem"), key=str(certs / f"{role}-key.pem"))


def client_environment(stack: Stack, endpoint: str, certs: Path | None = None, role: str = "") -> dict[str, str]:
    """The environment of a service process that is a client of the router (TLS as ``role``)."""
    environment = stack.environment | {"LOCNERF_ZENOH_MODE": "client", "LOCNERF_ZENOH_CONNECT": endpoint}
    if certs is not None:
        tls = tls_for(certs, role)
        environment |= {ENV_TLS["root_ca"]: tls.root_ca, ENV_TLS["certificate"]: tls.certificate, ENV_TLS["key"]: tls.key, ENV_TLS["mutual"]: "true"}
    return environment


def open_client(endpoint: str, tls: TlsConfig | None = None, timeout: float = 60.0):
    """A client bus of the router, retried until the router process accepts it."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return open_bus(TransportConfig(mode="client", connect=(endpoint,), tls=tls))
        except Exception:  # zenoh.ZError: the router is not listening yet
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)
