"""Choosing the compute device: ``auto`` means CUDA when present, else the CPU."""

from __future__ import annotations

import torch

from locnerf.errors import LocnerfInputError


def resolve_device(name: str = "auto") -> torch.device:
    """``auto`` | ``cpu`` | ``cuda`` | ``cuda:N`` -> a usable torch.device.

    Raises:
        LocnerfInputError: for an unknown name, or CUDA requested on a machine without it.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as error:
        raise LocnerfInputError(f"device {name!r}: expected auto, cpu, cuda or cuda:N") from error
    if device.type == "cuda" and not torch.cuda.is_available():
        raise LocnerfInputError(f"device {name!r}: CUDA is not available on this machine (use --device cpu or auto)")
    if device.type not in ("cpu", "cuda"):
        raise LocnerfInputError(f"device {name!r}: expected auto, cpu, cuda or cuda:N")
    return device
