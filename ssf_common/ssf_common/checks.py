"""Checks of numbers at the edges (flags, parameters): finite where physical, in range, one line when not."""

from __future__ import annotations

import math
import operator
from typing import Any

from ssf_common.errors import ConfigError

SEED_MAX = 2**32 - 1


def require_finite(
    value: Any,
    name: str,
    *,
    at_least: float | None = None,
    above: float | None = None,
    at_most: float | None = None,
) -> float:
    """`value` as a finite float within the bounds given, or one ConfigError line naming `name`."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if at_least is not None and number < at_least:
        raise ConfigError(f"{name} must be at least {at_least:g}, got {number:g}")
    if above is not None and number <= above:
        raise ConfigError(f"{name} must be above {above:g}, got {number:g}")
    if at_most is not None and number > at_most:
        raise ConfigError(f"{name} must be at most {at_most:g}, got {number:g}")
    return number


def require_seed(value: Any, name: str = "--seed") -> int:
    """A seed numpy takes: an integer from 0 to 2**32 - 1."""
    try:
        seed = operator.index(value)
    except TypeError:
        seed = None
    if isinstance(value, bool) or seed is None or not 0 <= seed <= SEED_MAX:
        raise ConfigError(f"{name} must be an integer from 0 to {SEED_MAX}, got {value!r}")
    return seed
