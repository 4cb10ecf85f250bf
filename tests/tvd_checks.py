"""Shared checks of covswarm.tvd against the references in tests/reference.py (not a test module).

``check_against_reference`` judges cells, masses and centroids against the shapely oracle;
``pieces`` assembles r = kappa (c - p) + dc/dt, the dense dc/dp and the neighbour sets from
covswarm.tvd.coverage (each verified on its own in test_coverage_reference and
test_derivatives), from which the tests build the control laws densely.
"""

from __future__ import annotations

import numpy as np
import shapely
from reference import (
    nearest_point,
    reference_cells,
    scale_of,
    signed_area,
)
from shapely.geometry import Polygon

from covswarm.tvd import coverage

REL = 1e-9


def check_against_reference(positions: np.ndarray, polygon: np.ndarray) -> None:
    """cells() and mass_centroid() agree with the shapely oracle for this configuration."""
    area = abs(signed_area(polygon))
    diam = scale_of(polygon)
    ref = reference_cells(positions, polygon)
    got = coverage.cells(positions, polygon)
    mass, cen = coverage.mass_centroid(positions, polygon)
    n = len(positions)
    assert len(got) == n
    assert mass.shape == (n,) and cen.shape == (n, 2)
    assert mass.dtype == np.float64 and cen.dtype == np.float64
    assert np.all(np.isfinite(mass)) and np.all(np.isfinite(cen))
    for i in range(n):
        cell = np.asarray(got[i])
        assert cell.ndim == 2 and cell.shape[1] == 2, (i, cell.shape)
        tiny = 1e-3 * REL * area
        if (
            (ref[i] is None or ref[i].area <= tiny)
            and (len(cell) == 0 or abs(signed_area(cell)) <= tiny)
            and (ref[i] is None) != (len(cell) == 0)
        ):
            # a sliver cell (e.g. robot outside S barely reaching it): empty or not is
            # round-off; only the mass is judged
            assert abs(mass[i]) <= 2 * tiny
            continue
        if ref[i] is None:
            assert cell.shape == (0, 2), f"robot {i}: expected an empty cell, got {cell}"
            assert mass[i] == 0.0, (i, mass[i])
            np.testing.assert_allclose(
                cen[i], nearest_point(polygon, positions[i]), rtol=0, atol=REL * diam
            )
            continue
        assert cell.shape[0] >= 3, f"robot {i}: expected a cell, got {cell}"
        assert signed_area(cell) > 0, f"robot {i}: cell is not CCW"
        mine = Polygon(cell)
        assert mine.is_valid, f"robot {i}: invalid cell polygon {cell}"
        sym = mine.symmetric_difference(ref[i]).area
        assert sym <= REL * area, f"robot {i}: symmetric difference {sym / area:.3g} of |S|"
        assert abs(mass[i] - ref[i].area) <= REL * area, (i, mass[i], ref[i].area)
        c_ref = np.array(ref[i].centroid.coords[0])
        err = np.linalg.norm(cen[i] - c_ref)
        assert err <= REL * diam, f"robot {i}: centroid off by {err / diam:.3g} diam(S)"
    # the non-empty cells partition S
    assert abs(mass.sum() - area) <= REL * area * max(1, n) ** 0.5


def whole_domain(polygon, V):
    """Centroid of S (shapely) and its rate (a lone robot's cell is S)."""
    centroid = np.array(shapely.Polygon(polygon).centroid.coords[0])
    return centroid, coverage.centroid_rate(centroid[None], polygon, V)[0]


def pieces(positions, polygon, V, kappa, feedforward=True):
    """(r (n, 2), dc/dp (2n, 2n) with empty cells' rows zeroed, neighbour sets) of the team.

    An empty cell's robot heads for the centroid of S (r from ``whole_domain``).
    """
    mass, c = coverage.mass_centroid(positions, polygon)
    rate = coverage.centroid_rate(positions, polygon, V)
    empty = mass == 0
    if empty.any():
        c_s, rate_s = whole_domain(polygon, V)
        c[empty], rate[empty] = c_s, rate_s
    r = kappa * (c - positions)
    if feedforward:
        r = r + rate
    J = coverage.centroid_jacobian(positions, polygon).copy()
    J[np.repeat(empty, 2), :] = 0.0
    return r, J, coverage.neighbors(positions, polygon)
