"""Property-based tests (hypothesis) of degenerate inputs to tvd.coverage and tvd.control.

Random geometry comes from numpy generators seeded by hypothesis (shrinking is on the
seed and the structural parameters). Every output must be finite, velocities bounded by
the documented guard (A * max |r|, A = control.MAX_AMPLIFICATION), and cells must still match the
shapely oracle where the answer is well defined.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from reference import (
    as_cw,
    motion,
    nearest_point,
    random_convex_polygon,
    random_robots,
    reference_mass_centroid,
    scale_of,
    signed_area,
)
from shapely.geometry import Point, Polygon
from tvd_checks import check_against_reference, pieces

from covswarm.tvd import control, coverage

A = control.MAX_AMPLIFICATION

# CI: 25 derandomized examples per property. For a deeper local run:
# COVSWARM_STRESS=500 pytest tests/test_degenerate.py (random, not derandomized)
_STRESS = int(os.environ.get("COVSWARM_STRESS", "0"))
SETTINGS = settings(deadline=None, max_examples=_STRESS or 25, derandomize=not _STRESS)
seeds = st.integers(0, 2**32 - 1)


def all_outputs(positions, polygon, V, kappa=1.0):
    """Call every public function; check shapes and finiteness; return the results."""
    n = len(positions)
    out = {
        "cells": coverage.cells(positions, polygon),
        "mc": coverage.mass_centroid(positions, polygon),
        "nb": coverage.neighbors(positions, polygon),
        "J": coverage.centroid_jacobian(positions, polygon),
        "rate": coverage.centroid_rate(positions, polygon, V),
        "err": coverage.aggregate_error(positions, polygon),
        "c": control.tvd_c(positions, polygon, V, kappa),
        "d1": control.tvd_d1(positions, polygon, V, kappa),
    }
    mass, cen = out["mc"]
    assert len(out["cells"]) == n and len(out["nb"]) == n
    assert mass.shape == (n,) and cen.shape == (n, 2)
    assert out["J"].shape == (2 * n, 2 * n) and out["rate"].shape == (n, 2)
    for key in ("J", "rate", "c", "d1"):
        assert np.all(np.isfinite(out[key])), key
    assert np.all(np.isfinite(mass)) and np.all(np.isfinite(cen))
    assert np.isfinite(out["err"]) and out["err"] >= 0
    assert np.all(mass >= 0)
    area = abs(signed_area(polygon))
    assert abs(mass.sum() - area) <= 1e-9 * area
    # every centroid lies in S (up to round-off)
    S = Polygon(polygon)
    for c in cen:
        assert S.exterior.distance(Point(c)) <= 1e-9 * scale_of(polygon) or S.covers(Point(c))
    r, _, _ = pieces(positions, polygon, V, kappa)
    bound = A * np.max(np.linalg.norm(r, axis=1))
    assert np.all(np.linalg.norm(out["d1"], axis=1) <= bound * (1 + 1e-9) + 1e-300)
    # damped TVD-C: kappa (c - p) + v(p) plus a correction whose rows are capped at
    # A max |dc/dt| (tvd/control.py)
    feedback = np.linalg.norm(pieces(positions, polygon, V, kappa, False)[0], axis=1).max()
    field = np.linalg.norm(control.affine_field(polygon, V)(positions), axis=1).max()
    bound_c = feedback + field + A * np.linalg.norm(out["rate"], axis=1).max()
    assert np.all(np.linalg.norm(out["c"], axis=1) <= bound_c * (1 + 1e-9) + 1e-300)
    assert np.all(np.isfinite(control.tvd_da(positions, polygon, V, kappa)))
    return out


def case(seed, n, outside=0.0):
    rng = np.random.default_rng(seed)
    polygon = random_convex_polygon(rng)
    positions = random_robots(rng, polygon, n, outside_fraction=outside)
    _, V = motion(["translate", "scale", "rotate", "combo"][seed % 4], polygon, rng)
    return rng, polygon, positions, V


@SETTINGS
@given(seeds)
def test_single_robot_cell_is_s(seed):
    rng, polygon, p, V = case(seed, 1)
    out = all_outputs(p, polygon, V)
    area = signed_area(polygon)
    assert Polygon(out["cells"][0]).symmetric_difference(Polygon(polygon)).area <= 1e-9 * area
    np.testing.assert_allclose(out["J"], 0, atol=1e-12)
    # c = centroid(S) moves with S; for an affine motion of the vertices that is exact
    P, Vv = motion("affine", polygon, rng)
    expected = (
        np.array(Polygon(P(1e-6)).centroid.coords[0]) - Polygon(P(-1e-6)).centroid.coords[0]
    ) / 2e-6
    got = coverage.centroid_rate(p, polygon, Vv)[0]
    assert np.linalg.norm(got - expected) <= 1e-5 * np.max(np.abs(Vv))


@SETTINGS
@given(seeds, st.integers(2, 12), st.integers(1, 4))
def test_coincident_robots(seed, n, copies):
    rng, polygon, p, V = case(seed, n, outside=0.2)
    src = rng.integers(n, size=copies)
    positions = np.vstack([p, p[src]])
    order = rng.permutation(len(positions))
    positions = positions[order]
    out = all_outputs(positions, polygon, V)
    check_against_reference(positions, polygon)
    mass, cen = out["mc"]
    for i in range(len(positions)):
        if any(np.array_equal(positions[i], positions[j]) for j in range(i)):
            assert mass[i] == 0 and out["nb"][i] == set() and len(out["cells"][i]) == 0
            np.testing.assert_allclose(cen[i], nearest_point(polygon, positions[i]), atol=1e-12)


@SETTINGS
@given(seeds, st.integers(2, 15), st.sampled_from(["random", "horizontal", "vertical"]))
def test_collinear_robots(seed, n, direction):
    rng, polygon, _, V = case(seed, 1)
    c = np.array(Polygon(polygon).centroid.coords[0])
    d = {"random": rng.normal(size=2), "horizontal": [1.0, 0.0], "vertical": [0.0, 1.0]}[direction]
    d = np.asarray(d) / np.linalg.norm(d)
    ts = rng.uniform(-0.7, 0.7, n) * scale_of(polygon)
    if rng.random() < 0.3:
        ts = np.linspace(-0.3, 0.3, n) * scale_of(polygon)  # evenly spaced
    positions = c + ts[:, None] * d
    all_outputs(positions, polygon, V)
    check_against_reference(positions, polygon)


@SETTINGS
@given(seeds, st.integers(1, 10), st.floats(1.5, 100))
def test_robots_outside_head_for_s(seed, n, distance):
    """Robots far outside S (cells empty) move straight toward the centroid of S."""
    rng, polygon, p, _ = case(seed, n)
    diam = scale_of(polygon)
    far = polygon.mean(axis=0) + distance * diam * np.array([np.cos(seed), np.sin(seed)])
    far2 = far + 0.3 * diam * rng.normal(size=(3, 2))
    positions = np.vstack([p, far2])
    static = np.zeros_like(polygon)
    out = all_outputs(positions, polygon, static, kappa=1.7)
    check_against_reference(positions, polygon)
    mass, _ = out["mc"]
    for i in range(n, n + 3):
        if mass[i] > 0:
            continue
        target = np.array(Polygon(polygon).centroid.coords[0])
        for key in ("c", "d1"):
            np.testing.assert_allclose(out[key][i], 1.7 * (target - positions[i]), atol=1e-9 * diam)


@SETTINGS
@given(seeds, st.integers(0, 8), st.sampled_from(["edge", "vertex"]))
def test_robot_on_the_boundary(seed, n, where):
    """A robot exactly on dS (axis-aligned edge, or at a vertex) is an ordinary robot."""
    rng = np.random.default_rng(seed)
    w, h = rng.uniform(0.5, 5, 2)
    rect = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    polygon = random_convex_polygon(rng) if where == "vertex" else rect
    others = random_robots(rng, polygon, n)
    if where == "edge":
        b = np.array([[rng.uniform(0, w), 0.0], [w, rng.uniform(0, h)], [0.0, h / 3]])
    else:
        b = polygon[rng.choice(len(polygon), size=2, replace=False)]
    positions = np.vstack([others, b])
    V = rng.normal(size=polygon.shape)
    out = all_outputs(positions, polygon, V)
    check_against_reference(positions, polygon)
    assert np.all(out["mc"][0][n:] > 0)


@SETTINGS
@given(seeds, st.integers(2, 10), st.floats(-15, -5))
def test_nearly_coincident_robots(seed, n, log_gap):
    rng, polygon, p, V = case(seed, n)
    diam = scale_of(polygon)
    u = rng.normal(size=2)
    q = p[0] + 10**log_gap * diam * u / np.linalg.norm(u)
    positions = np.vstack([p, q])
    out = all_outputs(positions, polygon, V)
    mass, cen = out["mc"]
    area = signed_area(polygon)
    # either the pair is split by its bisector (exact answer) or, below the code's
    # coincidence tolerance, the later robot is treated as a duplicate
    m_ref, c_ref = reference_mass_centroid(positions, polygon)
    m_dup, c_dup = reference_mass_centroid(positions[:-1], polygon)
    exact = np.allclose(mass, m_ref, atol=1e-9 * area) and np.allclose(cen, c_ref, atol=1e-9 * diam)
    dup = (
        mass[-1] == 0
        and np.allclose(mass[:-1], m_dup, atol=1e-9 * area)
        and np.allclose(cen[:-1], c_dup, atol=1e-9 * diam)
    )
    assert exact or dup
    if log_gap > -9:
        assert exact


@SETTINGS
@given(seeds, st.integers(1, 20), st.integers(0, 9))
def test_cw_equals_ccw(seed, n, shift):
    rng, polygon, positions, V = case(seed, n, outside=0.2)
    cw, Vcw = as_cw(polygon, V, shift=shift % len(polygon))
    diam = scale_of(polygon)
    vs = np.max(np.abs(V))
    a = all_outputs(positions, polygon, V)
    b = all_outputs(positions, cw, Vcw)
    np.testing.assert_allclose(b["mc"][0], a["mc"][0], atol=1e-12 * diam**2)
    np.testing.assert_allclose(b["mc"][1], a["mc"][1], atol=1e-12 * diam)
    np.testing.assert_allclose(b["J"], a["J"], atol=1e-9)
    np.testing.assert_allclose(b["rate"], a["rate"], atol=1e-9 * vs)
    assert a["nb"] == b["nb"]
    for key in ("c", "d1"):
        np.testing.assert_allclose(b[key], a[key], atol=1e-9 * (diam + vs))
    for ca, cb in zip(a["cells"], b["cells"], strict=True):
        assert len(ca) == len(cb) == 0 or (
            Polygon(ca).symmetric_difference(Polygon(cb)).area <= 1e-12 * diam**2
        )


# ---------------------------------------------------------------------------------------
# Invalid input
# ---------------------------------------------------------------------------------------

SQ = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
_ANGLES = (
    2 * np.pi * np.arange(coverage.MAX_POLYGON_VERTICES + 1) / (coverage.MAX_POLYGON_VERTICES + 1)
)
INVALID_POLYGONS = {
    "non-convex": (np.array([[0, 0], [2, 0], [1, 0.5], [2, 2], [0, 2]], float), r"convex"),
    "too-many-vertices": (np.c_[np.cos(_ANGLES), np.sin(_ANGLES)], r"1024"),
    "self-intersecting": (
        np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float),
        r"self-intersect|convex|simple",
    ),
    "star": (
        np.array([[np.cos(a), np.sin(a)] for a in np.arange(5) * 4 * np.pi / 5]),
        r"self-intersect|convex|simple|wind",
    ),
    "zero-area": (
        np.array([[1.0, 1.0]] * 4),
        r"area|degenerate|distinct|duplicate|repeat|zero-length|collinear",
    ),
    "collinear": (np.array([[0, 0], [1, 1], [2, 2], [3, 3]], float), r"area|collinear|degen"),
    "nan": (np.array([[0, 0], [1, 0], [np.nan, 1], [0, 1]], float), r"nan|finite"),
    "inf": (np.array([[0, 0], [1, 0], [np.inf, 1], [0, 1]], float), r"inf|finite"),
    "two-vertices": (np.array([[0, 0], [1, 0]], float), r"3|three|vertices|at least"),
    "3d": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), r"shape|\(k, ?2\)|column"),
    "flat": (np.array([0.0, 0.0, 1.0, 0.0, 0.0, 1.0]), r"shape|\(k, ?2\)|dimension"),
}


@pytest.mark.parametrize("name", list(INVALID_POLYGONS))
def test_invalid_polygon_raises(name):
    poly, pattern = INVALID_POLYGONS[name]
    with pytest.raises(ValueError, match=f"(?i){pattern}"):
        coverage.validate_polygon(poly)
    k = len(poly) if poly.ndim == 2 else 3
    p = np.array([[0.5, 0.5], [0.2, 0.3]])
    calls = [
        lambda: coverage.cells(p, poly),
        lambda: coverage.mass_centroid(p, poly),
        lambda: coverage.neighbors(p, poly),
        lambda: coverage.centroid_jacobian(p, poly),
        lambda: coverage.centroid_rate(p, poly, np.zeros((k, 2))),
        lambda: coverage.aggregate_error(p, poly),
        lambda: control.tvd_c(p, poly, np.zeros((k, 2)), 1.0),
        lambda: control.tvd_d1(p, poly, np.zeros((k, 2)), 1.0),
        lambda: control.local_velocity(0, dict(enumerate(p)), poly, np.zeros((k, 2)), 1.0),
    ]
    for call in calls:
        with pytest.raises(ValueError):
            call()


@pytest.mark.parametrize(
    "positions",
    [
        np.array([[0.5, np.nan]]),
        np.array([[0.5, 0.5], [np.inf, 0.2]]),
        np.array([[0.5, 0.5, 0.5]]),
        np.array([0.5, 0.5]),
    ],
    ids=["nan", "inf", "3-columns", "1-d"],
)
def test_invalid_positions_raise(positions):
    for call in (
        lambda: coverage.cells(positions, SQ),
        lambda: coverage.mass_centroid(positions, SQ),
        lambda: coverage.neighbors(positions, SQ),
        lambda: coverage.centroid_jacobian(positions, SQ),
        lambda: coverage.centroid_rate(positions, SQ, np.zeros((4, 2))),
        lambda: control.tvd_c(positions, SQ, np.zeros((4, 2)), 1.0),
        lambda: control.tvd_d1(positions, SQ, np.zeros((4, 2)), 1.0),
    ):
        with pytest.raises(ValueError, match=r"(?i)nan|inf|finite|shape|\(n, ?2\)|column"):
            call()


def test_polygon_velocity_shape_mismatch_raises():
    p = np.array([[0.5, 0.5]])
    for V in (np.zeros((3, 2)), np.zeros((4, 3)), np.zeros(8)):
        with pytest.raises(ValueError):
            coverage.centroid_rate(p, SQ, V)
        with pytest.raises(ValueError):
            control.tvd_d1(p, SQ, V, 1.0)


def test_validate_polygon_returns_ccw_copy():
    cw = SQ[::-1].copy()
    out = coverage.validate_polygon(cw)
    assert out.shape == (4, 2) and out.dtype == np.float64 and signed_area(out) > 0
    assert {tuple(v) for v in out} == {tuple(v) for v in SQ}
    out[0] = 99.0
    assert not np.any(cw == 99.0)
    ints = coverage.validate_polygon(np.array([[0, 0], [2, 0], [0, 2]]))
    assert ints.dtype == np.float64


@SETTINGS
@given(seeds, st.integers(1, 12), st.sampled_from(["midpoint", "closing"]))
def test_redundant_vertex_accepted_or_rejected_cleanly(seed, n, kind):
    """A collinear midpoint on an edge, or a repeated closing vertex: either a ValueError,
    or results identical to the polygon without it (midpoint velocity = the mean)."""
    rng, polygon, positions, V = case(seed, n, outside=0.2)
    if kind == "midpoint":
        mid, vmid = 0.5 * (polygon[0] + polygon[1]), 0.5 * (V[0] + V[1])
        poly2 = np.vstack([polygon[:1], mid, polygon[1:]])
        V2 = np.vstack([V[:1], vmid, V[1:]])
    else:
        poly2, V2 = np.vstack([polygon, polygon[:1]]), np.vstack([V, V[:1]])
    try:
        coverage.validate_polygon(poly2)
    except ValueError:
        return
    a = all_outputs(positions, polygon, V)
    b = all_outputs(positions, poly2, V2)
    diam = scale_of(polygon)
    np.testing.assert_allclose(b["mc"][1], a["mc"][1], atol=1e-12 * diam)
    np.testing.assert_allclose(b["rate"], a["rate"], atol=1e-9 * np.max(np.abs(V)))
    np.testing.assert_allclose(b["J"], a["J"], atol=1e-9)
