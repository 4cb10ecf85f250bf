"""trajectories.csv: every observed robot pose as one row ``t, id, x, y, theta``.

t: mission time (s since the mission's start); x, y in metres; theta in radians,
counter-clockwise from +x. Rows are in time order, robots in id order within a time. Load
it with ``numpy.loadtxt(path, delimiter=",", skiprows=1)`` or ``pandas.read_csv(path)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

TRAJECTORIES_FILE = "trajectories.csv"
HEADER = "t,id,x,y,theta\n"


class TrajectoryWriter:
    """Appends rows to trajectories.csv as poses are observed (the file stays valid CSV)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = self.path.open("w", encoding="utf-8", newline="")
        self._file.write(HEADER)
        self.rows = 0

    def write(self, t: float | np.ndarray, ids: Sequence[int], poses: np.ndarray) -> None:
        """t: mission time (s) of all rows, or (n,) one per row; ids: n robot ids; poses:
        (n, 3) x, y (m), theta (rad)."""
        times = np.broadcast_to(np.asarray(t, dtype=float), (len(ids),)).tolist()
        self._file.write(
            "".join(
                f"{when:.4f},{ident},{x:.5f},{y:.5f},{theta:.5f}\n"
                for when, ident, (x, y, theta) in zip(
                    times, ids, np.asarray(poses, dtype=float).tolist(), strict=True
                )
            )
        )
        self.rows += len(ids)

    def close(self) -> None:
        self._file.close()


def read_trajectories(path: str | Path) -> np.ndarray:
    """The rows of a trajectories.csv as an (R, 5) float array: t, id, x, y, theta."""
    rows = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if rows.shape[1:] != (5,):
        raise ValueError(f"{path}: expected 5 columns t,id,x,y,theta, got {rows.shape[1]}")
    return rows
