"""A Zenoh router session opened from a zenohd-style JSON5 file (``locnerf run router``).

zenohd is what docker compose runs; where it is not installed (tests, a bare host), the same
configuration file opened in ``router`` mode by the Python binding routes, authenticates (TLS)
and enforces access control the same way, since both are the same zenoh runtime.
"""

from __future__ import annotations

from pathlib import Path

import zenoh

from locnerf.errors import ConfigError


def router_config(path: Path, overrides: list[tuple[str, str]]) -> zenoh.Config:
    """The file's config with ``(key, json5 value)`` overrides, forced to router mode.

    Raises:
        FileNotFoundError: a missing file. ConfigError: a file or override zenoh rejects (names which).
    """
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: zenoh router configuration (JSON5) not found")
    try:
        conf = zenoh.Config.from_file(str(path))
    except Exception as error:  # zenoh raises its own ZError for any parse or schema failure
        raise ConfigError(f"{path}: not a valid zenoh configuration ({error})") from None
    for key, value in overrides + [("mode", '"router"')]:
        try:
            conf.insert_json5(key, value)
        except Exception as error:
            raise ConfigError(f"router override {key}:{value}: rejected by zenoh ({error})") from None
    return conf


class Router:
    """An open router session; :meth:`close` ends it."""

    def __init__(self, conf: zenoh.Config) -> None:
        self._session = zenoh.open(conf)

    @property
    def zid(self) -> str:
        """The router's Zenoh id."""
        return str(self._session.zid())

    def close(self) -> None:
        self._session.close()
