"""How fast a brain's cells are when compiled: a feasibility measure for issue 24's math.

Usage: pip install numba; .venv/bin/python scripts/compiled_cells.py [--brains 500]

Takes one tick's local views of the pack of ``covswarm bench --brain-tick`` (500 brains 0.2
m apart, deploy.bench; as its chunks handed them to covswarm.tvd.control.local_steps), and
builds each brain's own cell and its Voronoi neighbours' cells two ways:

- covswarm's batched numpy (``covswarm.tvd.control._view_cells``, timed inside the pack's
  own ``local_steps`` calls), which the agents use;
- :func:`view_cells`: S clipped by one bisector after the other (Sutherland-Hodgman), a
  plain loop per cell, compiled by numba (``numba.njit``) when it is installed.

It checks that the loop's own cells equal covswarm's (area and centroid, to 1e-9) and
prints both costs in us of CPU per brain. numba is not a dependency of covswarm; the loop
runs uncompiled without it (tests/test_compiled_cells_script.py checks its cells there).
docs/scaling.md quotes it.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path
from typing import Any

import numpy as np

from covswarm.deploy import bench

try:
    from numba import njit
except ImportError:  # the loop runs as Python: right, but slow
    njit = None


def _compiled(function: Any) -> Any:
    return function if njit is None else njit(cache=False)(function)


@_compiled
def clip(polygon: np.ndarray, n: int, a0: float, a1: float, c: float, out: np.ndarray) -> int:
    """The first ``n`` vertices of the convex ``polygon`` (rows x, y) clipped to a0 x + a1 y
    <= c, into ``out``; the number of vertices kept."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        px, py, qx, qy = polygon[i, 0], polygon[i, 1], polygon[j, 0], polygon[j, 1]
        dp, dq = a0 * px + a1 * py - c, a0 * qx + a1 * qy - c
        if dp <= 0.0:
            out[m, 0], out[m, 1] = px, py
            m += 1
        if (dp < 0.0 < dq) or (dq < 0.0 < dp):
            t = dp / (dp - dq)
            out[m, 0], out[m, 1] = px + t * (qx - px), py + t * (qy - py)
            m += 1
    return m


@_compiled
def view_cells(points: np.ndarray, owners: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(K, 3) area (m^2) and centroid x, y (m) of the Voronoi cells of ``owners`` (K,) among
    ``points`` (n, 2) within the convex ``polygon`` (k, 2, counter-clockwise)."""
    size = polygon.shape[0] + points.shape[0] + 1
    first, second = np.empty((size, 2)), np.empty((size, 2))
    out = np.zeros((owners.shape[0], 3))
    for k in range(owners.shape[0]):
        o = owners[k]
        n = polygon.shape[0]
        first[:n] = polygon
        a, b = first, second
        px, py = points[o, 0], points[o, 1]
        for j in range(points.shape[0]):
            if j == o:
                continue
            dx, dy = points[j, 0] - px, points[j, 1] - py
            n = clip(a, n, dx, dy, dx * (px + 0.5 * dx) + dy * (py + 0.5 * dy), b)
            a, b = b, a
            if n == 0:
                break
        if n < 3:
            continue
        area = cx = cy = 0.0
        ox, oy = a[0, 0], a[0, 1]  # moments about a vertex, as covswarm's cells take them
        for i in range(1, n - 1):
            x1, y1, x2, y2 = a[i, 0] - ox, a[i, 1] - oy, a[i + 1, 0] - ox, a[i + 1, 1] - oy
            cross = x1 * y2 - x2 * y1
            area += cross
            cx += cross * (x1 + x2)
            cy += cross * (y1 + y2)
        if area > 0.0:
            out[k, 0], out[k, 1], out[k, 2] = 0.5 * area, ox + cx / (3 * area), oy + cy / (3 * area)
    return out


def _sibling(name: str) -> Any:
    """scripts/``name``.py beside this one, imported (scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    assert spec is not None and spec.loader is not None, name
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def tick_views(brains: int) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], float]:
    """One tick's views of the bench's pack, each as (points (n, 2) m, owners: its robot's
    row then its neighbours', S (k, 2) m) with covswarm's own cell (area, centroid) checked
    against the loop's; and covswarm's cells' us of CPU per brain (``_view_cells``, timed
    inside the pack's own batches)."""
    from covswarm.tvd import control

    layout = bench.make_layout(brains, "cvt", 0, spacing=bench.BRAIN_TICK_SPACING)
    kept = _sibling("brain_tick_floor").one_ticks_batches(brains, layout)
    spent, cells = [0.0], control._view_cells

    def timed(*arguments: Any) -> Any:
        started = time.process_time()
        answer = cells(*arguments)
        spent[0] += time.process_time() - started
        return answer

    control._view_cells = timed
    try:
        steps = [
            step for batch, args in kept["steps"] for step in control.local_steps(batch, *args)
        ]
    finally:
        control._view_cells = cells
    views = [view for batch, _ in kept["steps"] for view in batch]
    out = []
    for view, step in zip(views, steps, strict=True):
        ids = list(view.positions)
        points = np.array([view.positions[i] for i in ids], dtype=float)
        rows = [ids.index(view.me)] + [ids.index(i) for i in sorted(step.neighbors)]
        polygon = np.ascontiguousarray(np.asarray(view.polygon, dtype=float))
        own = view_cells(points, np.array(rows[:1], dtype=np.int64), polygon)[0]
        assert abs(own[0] - step.area) <= 1e-9, (own, step.area)
        assert np.allclose(own[1:], step.centroid, rtol=0.0, atol=1e-9), (own, step.centroid)
        out.append((points, np.array(rows, dtype=np.int64), polygon))
    return out, spent[0] / len(views) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--brains", type=int, default=500)
    args = parser.parse_args()
    if njit is None:
        raise SystemExit("numba not found: pip install numba (the timing needs it compiled)")
    started = time.perf_counter()
    views, numpy_us = tick_views(args.brains)
    view_cells(*views[0])  # compiled on its first call
    took = time.perf_counter() - started
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"# {stamp}; {args.brains} views, own cells equal to covswarm's to 1e-9 ({took:.0f} s)")
    cells = np.mean([len(owners) for _, owners, _ in views])
    best = float("inf")
    for _ in range(5):
        started = time.process_time()
        for view in views:
            view_cells(*view)
        best = min(best, time.process_time() - started)
    print(f"| cells of a brain (its own and its {cells - 1:.1f} neighbours') | us of CPU |")
    print("|---|---|")
    print(f"| covswarm's batched numpy (_view_cells, in the pack's chunks) | {numpy_us:.1f} |")
    print(f"| one clip after the other, numba | {best / len(views) * 1e6:.1f} |")


if __name__ == "__main__":
    main()
