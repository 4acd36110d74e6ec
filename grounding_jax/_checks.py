"""Small input checks shared by the configs: clear ValueErrors that name the field."""

from __future__ import annotations

from typing import Any

import numpy as np


def require_int(name: str, value: Any, minimum: int) -> int:
    """Return ``value`` if it is an integer >= ``minimum``; else ValueError naming ``name``."""
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    return int(value)
