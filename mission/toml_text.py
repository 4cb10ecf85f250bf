"""TOML text for scenario files (writing; reading is tomllib's)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def toml_float(value: float) -> str:
    value = float(value)
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)


def toml_list(values: Any) -> str:
    return "[" + ", ".join(toml_float(v) for v in values) + "]"


def toml_points(points: np.ndarray) -> str:
    return "[" + ", ".join(toml_list(p) for p in points) + "]"


def toml_str(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
