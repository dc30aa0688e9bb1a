"""Transport configuration: embedded peer-to-peer on loopback by default, a router for compose.

Environment overrides (used by docker compose and ``locnerf up``): ``LOCNERF_ZENOH_MODE``
(peer | client), ``LOCNERF_ZENOH_CONNECT`` and ``LOCNERF_ZENOH_LISTEN`` (comma-separated
endpoints such as ``tcp/127.0.0.1:7447``), ``LOCNERF_ZENOH_CONNECT_RETRY`` (seconds a client keeps
retrying a router that is not up yet); TLS: ``LOCNERF_ZENOH_TLS_ROOT_CA``,
``LOCNERF_ZENOH_TLS_CERTIFICATE``, ``LOCNERF_ZENOH_TLS_KEY`` (PEM file paths) and
``LOCNERF_ZENOH_TLS_MUTUAL`` (``true`` | ``false``), see :class:`TlsConfig` and docs/SECURITY.md.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from locnerf.errors import ConfigError

ENV_MODE = "LOCNERF_ZENOH_MODE"
ENV_CONNECT = "LOCNERF_ZENOH_CONNECT"
ENV_LISTEN = "LOCNERF_ZENOH_LISTEN"
ENV_CONNECT_RETRY = "LOCNERF_ZENOH_CONNECT_RETRY"
ENV_TLS = {
    "root_ca": "LOCNERF_ZENOH_TLS_ROOT_CA",
    "certificate": "LOCNERF_ZENOH_TLS_CERTIFICATE",
    "key": "LOCNERF_ZENOH_TLS_KEY",
    "mutual": "LOCNERF_ZENOH_TLS_MUTUAL",
}
_CERTIFICATE_PEM = "-----BEGIN CERTIFICATE-----"
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def _check_pem(path: str, what: str, marker: str, expected: str) -> None:
    """Raise a ValueError naming ``path`` unless it is a readable text file holding ``marker``."""
    file = Path(path)
    if not file.is_file():
        raise ValueError(f"TLS {what} {path!r}: file not found (expected a PEM file, e.g. from `locnerf certs`)")
    try:
        text = file.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"TLS {what} {path!r}: not readable as a PEM text file ({error})") from None
    if marker not in text:
        raise ValueError(f"TLS {what} {path!r}: expected {expected}")


class TlsConfig(BaseModel):
    """TLS of a Zenoh session: endpoints are then ``tls/<host>:<port>``.

    With ``mutual`` on, both ends present a certificate signed by ``root_ca``: a router then
    refuses sessions without one, and its access control can grant rights by the certificate's
    common name (docs/SECURITY.md). Files are checked when the config is built.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    root_ca: str = Field(description="PEM file of the certificate authority that signed the peer's certificate.")
    certificate: str = Field("", description="PEM file of this process's certificate (needed to listen, and to connect with mutual TLS).")
    key: str = Field("", description="PEM file of this certificate's private key (PKCS#8 or SEC1).")
    mutual: bool = Field(True, description="Mutual TLS: present this certificate when connecting and require one from connecting peers.")

    @model_validator(mode="after")
    def _files(self) -> TlsConfig:
        _check_pem(self.root_ca, "root_ca", _CERTIFICATE_PEM, "a PEM certificate ('-----BEGIN CERTIFICATE-----')")
        if bool(self.certificate) != bool(self.key):
            raise ValueError(f"TLS certificate {self.certificate!r} and key {self.key!r}: expected both or neither")
        if self.mutual and not self.certificate:
            raise ValueError("TLS mutual = true: expected a certificate and key for this process")
        if self.certificate:
            _check_pem(self.certificate, "certificate", _CERTIFICATE_PEM, "a PEM certificate ('-----BEGIN CERTIFICATE-----')")
            _check_pem(self.key, "key", "PRIVATE KEY-----", "a PEM private key ('-----BEGIN ... PRIVATE KEY-----')")
        return self


class TransportConfig(BaseModel):
    """How a service opens its Zenoh session."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: Literal["peer", "client"] = Field("peer", description="Zenoh mode: peer (embedded default) or client (of a zenohd router).")
    connect: tuple[str, ...] = Field((), description="Endpoints to connect to, e.g. tcp/127.0.0.1:7447 or tcp/zenohd:7447.")
    listen: tuple[str, ...] = Field(("tcp/127.0.0.1:0",), description="Endpoints to listen on (peer mode); port 0 picks a free port, advertised by gossip.")
    connect_retry: float = Field(
        0.0,
        ge=0,
        description="Client mode: seconds to keep retrying the router when the session cannot reach it, with a backoff of "
        "0.25 s doubling up to 5 s, each failure logged (0: fail at once). Containers set it: a router may start after its clients.",
    )
    multicast_scouting: bool = Field(False, description="UDP multicast discovery (off: endpoints are explicit).")
    block_when_congested: bool = Field(
        False,
        description="Publishers wait when the network queue is full instead of dropping (the services drop: a stale sample "
        "is worth less than a blocked pose thread; locnerf fuzz blocks, so that every payload it counts is delivered).",
    )
    tls: TlsConfig | None = Field(None, description="TLS files and mutual authentication (None: plain tcp endpoints).")

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for endpoint in value:
            if "/" not in endpoint:
                raise ValueError(f"endpoint {endpoint!r}: expected <protocol>/<address>, e.g. tcp/127.0.0.1:7447")
        return value

    def with_environment(self, environ: dict[str, str] | None = None) -> TransportConfig:
        """This config with the ``LOCNERF_ZENOH_*`` variables applied."""
        environ = os.environ if environ is None else environ
        updates: dict[str, object] = {}
        if environ.get(ENV_MODE):
            updates["mode"] = environ[ENV_MODE]
        for name, field in ((ENV_CONNECT, "connect"), (ENV_LISTEN, "listen")):
            if name in environ:
                updates[field] = tuple(e.strip() for e in environ[name].split(",") if e.strip())
        if environ.get(ENV_CONNECT_RETRY):
            updates["connect_retry"] = environ[ENV_CONNECT_RETRY]
        tls = _tls_from_environment(self.tls, environ)
        if tls is not None:
            updates["tls"] = tls
        return TransportConfig.model_validate(self.model_dump() | updates)


def _tls_from_environment(current: TlsConfig | None, environ) -> dict[str, object] | None:
    """The TLS fields with the ``LOCNERF_ZENOH_TLS_*`` variables applied, None when none is set."""
    given = {field: environ[name] for field, name in ENV_TLS.items() if environ.get(name)}
    if not given:
        return None
    if "mutual" in given:
        flag = given["mutual"].strip().lower()
        if flag not in _TRUE + _FALSE:
            raise ConfigError(f"{ENV_TLS['mutual']}={given['mutual']!r}: expected true or false")
        given["mutual"] = flag in _TRUE
    base = current.model_dump() if current is not None else {}
    if "root_ca" not in base | given:
        raise ConfigError(f"TLS settings from the environment need {ENV_TLS['root_ca']} (the CA's PEM file)")
    return base | given
