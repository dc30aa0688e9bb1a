"""Stamps: whole nanoseconds, exact, on the wire; float seconds for arithmetic.

A ROS 2 stamp ``(sec, nanosec)`` does not survive a trip through float seconds: near 1.7e9 s
(Unix time today) doubles are 2⁻²² s ≈ 238 ns apart, so the stamp of an output can differ from
its input's by up to 119 ns, and exact time synchronisers (``message_filters``' ExactTime) never
pair them. Stamped wire messages therefore carry ``stamp_ns`` (int) beside ``stamp`` (float), and
outputs take their stamp from their input's nanoseconds.
"""

from __future__ import annotations

import math
from fractions import Fraction

NANOSECONDS_PER_SECOND = 1_000_000_000


def nanoseconds_from_seconds(seconds: float) -> int:
    """Float seconds -> the nearest whole nanoseconds (computed on the float's exact value, not on a rounded product).

    Raises:
        ValueError: ``seconds`` is not finite.
    """
    if not math.isfinite(seconds):
        raise ValueError(f"stamp {seconds} s: expected a finite number of seconds")
    return round(Fraction(seconds) * NANOSECONDS_PER_SECOND)


def seconds_from_nanoseconds(nanoseconds: int) -> float:
    """Whole nanoseconds -> the nearest float seconds (Python's int / int division is correctly rounded)."""
    return nanoseconds / NANOSECONDS_PER_SECOND
