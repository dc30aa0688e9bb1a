"""Configuration models filled from command-line flags, with validation errors that name the flag."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from locnerf.errors import LocnerfInputError

Model = TypeVar("Model", bound=BaseModel)


def flag_of(field: str) -> str:
    """The flag that sets ``field`` by default: ``camera_rate`` -> ``--camera-rate``."""
    return "--" + field.replace("_", "-")


def from_flags(model: type[Model], values: Mapping[str, Any], flags: Mapping[str, str] | None = None) -> Model:
    """``model`` validated from ``values`` (field -> value), most of them given on the command line.

    ``flags`` names the flag of a field where it is not :func:`flag_of` the field's name
    (``{"translation_drift": "--drift"}``).

    Raises:
        LocnerfInputError: a value the model refuses, naming its flag, e.g.
            ``--particles: must be greater than or equal to 1, got 0``.
    """
    try:
        return model.model_validate(dict(values))
    except ValidationError as error:
        problems = []
        for problem in error.errors():
            field = str(problem["loc"][0]) if problem["loc"] else ""
            flag = (flags or {}).get(field, flag_of(field))
            reason = problem["msg"].removeprefix("Value error, ").replace("Input should be", "must be", 1)
            problems.append(f"{flag}: {reason}, got {problem['input']!r}")
        raise LocnerfInputError("; ".join(problems)) from error
