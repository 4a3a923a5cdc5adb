"""Values an option takes from text: numbers in a range, and quantities with a unit.

Each parser takes the text a user wrote (on the command line, or a run file's value as
text) and returns the value, or raises ValueError with the reason in one phrase (``must be
an integer in 0..232, got 300``); the command line turns that into argparse's error, a run
file into ``FILE: KEY: why``. No argparse here: the option table
(``formation_ilc.config.option_table``) and the command line share these.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable

__all__ = ["int_in", "float_in", "quantity", "UNITS", "MAX_TRIAL", "MAX_SEED"]

#: trial indices are stored as float64 in metrics rows: exact up to 2^53
MAX_TRIAL = 2 ** 53
#: seeds go to ROS parameters (int64)
MAX_SEED = 2 ** 63 - 1

_DEG = math.pi / 180.0
#: an option's unit -> the units a value may be written in, with their factor to it
UNITS: dict[str, dict[str, float]] = {
    "deg": {"deg": 1.0, "rad": 1.0 / _DEG},
    "deg/s": {"deg/s": 1.0, "rad/s": 1.0 / _DEG},
    "deg/s^2": {"deg/s^2": 1.0, "rad/s^2": 1.0 / _DEG},
    "rad": {"rad": 1.0, "deg": _DEG},
    "rad/s": {"rad/s": 1.0, "deg/s": _DEG},
    "rad/s^2": {"rad/s^2": 1.0, "deg/s^2": _DEG},
}
_QUANTITY = re.compile(r"^\s*([-+]?[0-9.]+(?:[eE][-+]?[0-9]+)?)\s*([a-z][a-z/^0-9]*)\s*$")


def int_in(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """A parser of an integer in [lo, hi] (no upper bound with ``hi`` None)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise ValueError(f"expected an integer, got {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            bound = f">= {lo}" if hi is None or hi >= MAX_TRIAL else f"in {lo}..{hi}"
            if hi is not None and value > hi:
                bound = f"<= {hi}"
            raise ValueError(f"must be an integer {bound}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def float_in(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False,
             unit: str = "") -> Callable[[str], float]:
    """A parser of a finite number in [lo, hi] (``open_lo``: > lo); ``unit`` (one of
    UNITS) also takes the value written with a unit it converts from (``"100 deg/s"``,
    ``"1.7 rad/s"``), a bare number being in ``unit``."""

    def parse(text: str) -> float:
        value = quantity(text, unit) if unit in UNITS else _number(text)
        if lo is None and hi is None:
            return value
        low = -math.inf if lo is None else lo
        high = math.inf if hi is None else hi
        if not (math.isfinite(value) and (value > low if open_lo else value >= low)
                and value <= high):
            raise ValueError(_bound_phrase(lo, hi, open_lo, unit, text))
        return value

    parse.__name__ = "number"
    return parse


def _bound_phrase(lo: float | None, hi: float | None, open_lo: bool, unit: str,
                  text: str) -> str:
    if hi is None:
        return f"must be a finite number {'>' if open_lo else '>='} {lo:g}, got {text}"
    return (f"must be a number in {lo if lo is not None else -math.inf:g}..{hi:g}"
            f"{' ' + unit if unit else ''}, got {text}")


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"expected a number, got {text!r}") from None


def quantity(text: str, unit: str) -> float:
    """``text`` as a number in ``unit``: a bare number is in it, one written with another
    unit of the same kind (UNITS) is converted (``quantity("100 deg/s", "rad/s")``)."""
    try:
        return float(text)  # a bare number (nan and inf too: the bounds refuse them)
    except ValueError:
        pass
    m = _QUANTITY.match(str(text))
    if m is not None:
        try:
            float(m.group(1))
        except ValueError:
            m = None
    if m is None:
        raise ValueError(f"expected a number [{unit}] (or with its unit, e.g. '10 "
                         f"{next(iter(UNITS[unit]))}'), got {text!r}")
    value, written = float(m.group(1)), m.group(2)
    factors = UNITS[unit]
    if written not in factors:
        raise ValueError(f"unit {written!r}: expected {' or '.join(factors)}, got {text!r}")
    return value * factors[written]
