"""Checks of a map file's records before anything is built from them.

A map file's archive passed its checksum and holds only tensors and plain data, but its entries
may still be missing, of the wrong type or of the wrong shape (an edited file, a bug in another
writer). The backends check their records with these helpers and refuse with
:class:`MapFileError` naming the entry, before allocating anything the record sizes.
"""

from __future__ import annotations

from typing import Any, TypeVar

import torch
from pydantic import BaseModel, ValidationError

from locnerf.errors import MapFileError

Model = TypeVar("Model", bound=BaseModel)


def entry(record: Any, key: str, kind: type | tuple[type, ...], what: str) -> Any:
    """``record[key]``, checked to be an instance of ``kind``.

    Raises:
        MapFileError: ``record`` is not a dict, lacks ``key``, or holds something else there.
    """
    if not isinstance(record, dict):
        raise MapFileError(f"{what}: a {type(record).__name__}, expected a dict")
    if key not in record:
        raise MapFileError(f"{what}: missing {key} (no such entry)")
    value = record[key]
    if not isinstance(value, kind):
        names = " or ".join(k.__name__ for k in (kind if isinstance(kind, tuple) else (kind,)))
        raise MapFileError(f"{what}: entry {key!r} is a {type(value).__name__}, expected {names}")
    return value


def validated(model: type[Model], data: Any, what: str) -> Model:
    """``model.model_validate(data)``, its errors as one :class:`MapFileError` line."""
    try:
        return model.model_validate(data)
    except ValidationError as error:
        problems = "; ".join(f"{'.'.join(str(part) for part in problem['loc']) or 'value'}: {problem['msg']}" for problem in error.errors())
        raise MapFileError(f"{what}: {problems}") from None


def tensor_of_shape(value: Any, shape: tuple[int, ...], what: str) -> torch.Tensor:
    """``value`` checked to be a finite floating-point tensor of ``shape``.

    Raises:
        MapFileError: naming ``what``, the shape found and the shape expected.
    """
    if not isinstance(value, torch.Tensor) or not value.dtype.is_floating_point:
        raise MapFileError(f"{what}: a {getattr(value, 'dtype', type(value).__name__)}, expected a floating-point tensor of shape {shape}")
    if tuple(value.shape) != shape:
        raise MapFileError(f"{what}: shape {tuple(value.shape)}, expected {shape}")
    if not bool(torch.isfinite(value).all()):
        raise MapFileError(f"{what}: holds NaN or infinite values")
    return value


def check_state_dict(weights: Any, expected: dict[str, torch.Tensor], what: str) -> None:
    """``weights`` checked to hold exactly ``expected``'s names, each a tensor of the same shape and kind
    (boolean, or floating point), so that ``load_state_dict`` cannot fail on it.

    Raises:
        MapFileError: naming the missing, unexpected or mis-shaped entries.
    """
    if not isinstance(weights, dict):
        raise MapFileError(f"{what}: a {type(weights).__name__}, expected a dict of tensors")
    missing, unexpected = sorted(set(expected) - set(weights)), sorted(set(weights) - set(expected))
    if missing or unexpected:
        raise MapFileError(f"{what}: missing {missing or 'nothing'}, unexpected {unexpected or 'nothing'}")
    for name, reference in expected.items():
        value = weights[name]
        if not isinstance(value, torch.Tensor) or tuple(value.shape) != tuple(reference.shape):
            raise MapFileError(f"{what}: {name} of shape {tuple(getattr(value, 'shape', ()))}, expected {tuple(reference.shape)}")
        if (value.dtype == torch.bool) != (reference.dtype == torch.bool) or not (value.dtype == torch.bool or value.dtype.is_floating_point):
            raise MapFileError(f"{what}: {name} of dtype {value.dtype}, expected {reference.dtype}")
