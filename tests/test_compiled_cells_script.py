"""scripts/compiled_cells.py's loop builds the Voronoi cells covswarm builds: against
shapely's Voronoi diagram on random layouts, and against the pack's own cells on one tick
of a small bench team (its tick_views checks each brain's own cell to 1e-9). Run as Python
here (numba is not a dependency); the timing compiles the same code."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from script_modules import load_script

script = load_script("compiled_cells")


@pytest.mark.parametrize("seed", range(6))
def test_the_loops_cells_are_shapelys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 25))
    angles = np.sort(rng.uniform(0.0, 2 * np.pi, 7))
    polygon = np.column_stack([2.0 * np.cos(angles), 1.5 * np.sin(angles)])  # convex, CCW
    points = rng.uniform(-1.2, 1.2, (n, 2))
    cells = script.view_cells(points, np.arange(n, dtype=np.int64), polygon)
    region = shapely.Polygon(polygon)
    diagram = shapely.voronoi_polygons(shapely.MultiPoint(points), extend_to=region.buffer(5))
    for i, (x, y) in enumerate(points):
        piece = next(p for p in diagram.geoms if p.contains(shapely.Point(x, y)))
        reference = piece.intersection(region)
        assert cells[i, 0] == pytest.approx(reference.area, abs=1e-9)
        if reference.area > 1e-12:
            assert cells[i, 1:] == pytest.approx(
                [reference.centroid.x, reference.centroid.y], abs=1e-9
            )


def test_one_ticks_views_give_the_packs_own_cells() -> None:
    views, numpy_us = script.tick_views(30)
    assert len(views) == 30 and numpy_us > 0.0
    for points, owners, polygon in views:
        assert owners[0] not in owners[1:] and len(points) >= len(owners)
        assert polygon.shape[1] == 2
