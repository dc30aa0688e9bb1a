"""Errors that report bad input: a flag, a configuration, a map file, a data set.

Every one is a :class:`LocnerfInputError`, a ``ValueError`` whose message names the bad value and
what was expected. The ``locnerf`` command reports these as one line (exit code 2); any other
exception is a bug and keeps its traceback.
"""

from __future__ import annotations


class LocnerfInputError(ValueError):
    """Input from the user or their files that locnerf cannot use (the message says why)."""


class ConfigError(LocnerfInputError):
    """A configuration (TOML file, preset name, environment variable) that is unreadable or invalid."""


class MapFileError(LocnerfInputError):
    """A map file (or a checkpoint to convert) that cannot be loaded: truncated, corrupt, not a map,
    a newer format, a checksum mismatch, objects that only code could rebuild, an unknown backend."""


class DatasetError(LocnerfInputError):
    """A data set, sequence or log folder whose files are missing pieces, malformed or inconsistent."""
