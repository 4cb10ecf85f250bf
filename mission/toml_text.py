"""TOML text for scenario files (writing; reading is tomllib's)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from covswarm.mission.motion import DensityPath


def toml_float(value: float) -> str:
    value = float(value)
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)


def toml_list(values: Any) -> str:
    return "[" + ", ".join(toml_float(v) for v in values) + "]"


def toml_points(points: np.ndarray) -> str:
    return "[" + ", ".join(toml_list(p) for p in points) + "]"


def density_toml(path: DensityPath) -> str:
    table = path.to_table()
    lines = [f"\n[density]\nfloor = {toml_float(table['floor'])}"]
    for bump in table["bumps"]:
        lines.append("\n[[density.bumps]]")
        for key, value in bump.items():
            text = toml_points(value) if key in ("cov", "cov_rate") else (
                toml_list(value) if isinstance(value, list) else toml_float(value)
            )  # fmt: skip
            lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def toml_str(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
