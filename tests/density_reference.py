"""The first density quadrature of covswarm.tvd.density, kept as a reference for the tests.

Gauss-Legendre on every cell, nothing specific to Gaussians: masses, centroids and the
dphi/dt integral with an 8x8 collapsed (Duffy) rule on a fan of triangles of each cell, the
edge integrals of dc/dp and of the boundary term with 8-point Gauss-Legendre, every triangle
and edge subdivided so that a piece is at most RESOLUTION standard deviations of the
narrowest bump long (at most MAX_SUBDIVISION pieces per side). Accurate to 1e-10 while a cell
is under 24 sigma wide, 1e-6 at 48 sigma, 2e-4 at 200 (the subdivision caps). It evaluates
phi and dphi/dt only through ``Density.phi`` / ``Density.rate``, so it shares none of the
closed forms under test. ``QuadratureDensity(density)`` is a coverage DensityModel.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from covswarm.tvd.coverage import (
    CellBatch,
    CoverageDomain,
    as_complex,
    as_vectors,
    cross,
    nearest_point_derivatives,
)
from covswarm.tvd.density import Density

TRIANGLE_ORDER = 8
EDGE_ORDER = 8
RESOLUTION = 4.0
MAX_SUBDIVISION = 8


@dataclass(frozen=True, eq=False)
class QuadratureDensity:
    """``density`` integrated by quadrature: the covswarm.tvd.coverage DensityModel methods."""

    density: Density

    def weigh(self, batch: CellBatch) -> CellBatch:
        return weigh(self.density, batch)

    def jacobian_blocks(
        self, batch: CellBatch, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return jacobian_blocks(self.density, batch, points)

    def jacobian_times(
        self, batch: CellBatch, points: np.ndarray, own: np.ndarray, others: np.ndarray
    ) -> np.ndarray:
        off, diagonal = jacobian_blocks(self.density, batch, points)
        others = np.where(batch.shared, others, 0.0)
        return as_complex(
            np.einsum("kab,kb->ka", diagonal, as_vectors(own))
            + np.einsum("klab,klb->ka", off, as_vectors(others))
        )

    def boundary_rates(
        self, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
    ) -> np.ndarray:
        return centroid_rates(self.density, batch, points, domain)


# ---------------------------------------------------------------------------- quadrature


@cache
def _gauss_legendre(order: int, pieces: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre on [0, 1]: ``pieces`` equal parts. (P,) nodes and weights."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    starts = np.arange(pieces)[:, None] / pieces
    return (starts + 0.5 * (nodes + 1.0) / pieces).ravel(), np.tile(0.5 * weights / pieces, pieces)


@cache
def _triangle_rule(order: int, pieces: int) -> tuple[np.ndarray, np.ndarray]:
    """Rule on the unit triangle (0,0), (1,0), (0,1) split into pieces^2 similar ones.

    Returns (a, b) coordinates (P, 2) of q = v0 + a (v1 - v0) + b (v2 - v0) and weights (P,)
    summing to 1/2 (the triangle's area). Base rule: Duffy collapse of the square,
    (u, v) -> (u, (1 - u) v) with Jacobian 1 - u, Gauss-Legendre in u and v.
    """
    nodes, weights = _gauss_legendre(order, 1)
    u, v = np.meshgrid(nodes, nodes, indexing="ij")
    base = np.stack([u.ravel(), ((1.0 - u) * v).ravel()], axis=1)
    base_weight = (weights[:, None] * weights[None, :] * (1.0 - u)).ravel()
    corners, axes = [], []
    for i in range(pieces):
        for j in range(pieces - i):
            corners.append((i, j))  # upright: corner (i, j), sides +a and +b
            axes.append(((1, 0), (0, 1)))
            if i + j < pieces - 1:  # inverted: corner (i + 1, j + 1), sides -a and -b
                corners.append((i + 1, j + 1))
                axes.append(((-1, 0), (0, -1)))
    corner = np.array(corners, dtype=float) / pieces  # (T, 2)
    side = np.array(axes, dtype=float) / pieces  # (T, 2 sides, 2)
    points = corner[:, None, :] + np.einsum("pk,tkc->tpc", base, side)
    return points.reshape(-1, 2), np.tile(base_weight / pieces**2, len(corners))


def subdivision(density: Density, batch: CellBatch) -> np.ndarray:
    """(K,) pieces per side for each cell: pieces <= RESOLUTION sigma_min long, capped.

    Per cell, so that a cell gets the same quadrature whichever batch it is built in (a
    robot's local view or the whole team).
    """
    if not np.isfinite(density.sigma_min):
        return np.ones(len(batch.owners), dtype=int)
    origin = batch.start[:, :1]
    reach = np.maximum(np.abs(batch.start - origin), np.abs(batch.end - origin))
    extent = np.max(np.where(batch.present, reach, 0.0), axis=1)
    pieces = np.ceil(extent / (RESOLUTION * density.sigma_min))
    return np.clip(pieces, 1, MAX_SUBDIVISION).astype(int)


@cache
def _padded_rules(
    rule: Callable[[int, int], tuple[np.ndarray, np.ndarray]], order: int, most: int
) -> tuple[np.ndarray, np.ndarray]:
    """rule(order, s) for s = 1..most stacked: points (most + 1, P, ...) and weights
    (most + 1, P), P the size of the finest, coarser rules padded with zero weights."""
    rules = [rule(order, pieces) for pieces in range(1, most + 1)]
    size = len(rules[-1][1])
    points = np.zeros((most + 1, size, *rules[-1][0].shape[1:]))
    weights = np.zeros((most + 1, size))
    for pieces, (nodes, node_weights) in enumerate(rules, start=1):
        points[pieces, : len(node_weights)] = nodes
        weights[pieces, : len(node_weights)] = node_weights
    return points, weights


def _cell_rules(
    rule: Callable[[int, int], tuple[np.ndarray, np.ndarray]], order: int, pieces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's rule, padded to the batch's finest: (K, P, ...) points, (K, P) weights."""
    points, weights = _padded_rules(rule, order, int(pieces.max(initial=1)))
    return points[pieces], weights[pieces]


def _trim(batch: CellBatch) -> int:
    """Number of leading lines that hold every present edge (the rest are padding)."""
    return max(int(batch.present.sum(axis=1).max(initial=0)), 1)


def _fan(batch: CellBatch, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quadrature over each cell as a fan of triangles (v0, start_l, end_l).

    Returns origin v0 (K, 1, 1, 2), points q (K, L, P, 2) and weights (K, L, P) with the
    triangle's area folded in (zero on padding lines and on the degenerate triangles at v0).
    """
    lines = _trim(batch)
    start, end = as_vectors(batch.start[:, :lines]), as_vectors(batch.end[:, :lines])
    origin = start[:, :1, None, :]
    ab, weights = _cell_rules(_triangle_rule, TRIANGLE_ORDER, pieces)
    a, b = start[:, :, None, :] - origin, end[:, :, None, :] - origin
    q = origin + ab[:, None, :, 0, None] * a + ab[:, None, :, 1, None] * b
    twice_area = np.where(batch.present[:, :lines], cross(a[:, :, 0], b[:, :, 0]), 0.0)
    return origin, q, twice_area[..., None] * weights[:, None, :]


def _edges(batch: CellBatch, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Gauss-Legendre points q (K, L, G, 2) on every edge and weights ds (K, L, G).

    ds includes the edge length; zero on padding lines. Also returns the lines kept.
    """
    lines = _trim(batch)
    start, end = as_vectors(batch.start[:, :lines]), as_vectors(batch.end[:, :lines])
    nodes, weights = _cell_rules(_gauss_legendre, EDGE_ORDER, pieces)
    d = end - start
    q = start[:, :, None, :] + nodes[:, None, :, None] * d[:, :, None, :]
    length = np.where(batch.present[:, :lines], np.linalg.norm(d, axis=-1), 0.0)
    return q, length[..., None] * weights[:, None, :], lines


# ---------------------------------------------------------------------------- integrals


def weigh(density: Density, batch: CellBatch) -> CellBatch:
    """``batch`` with m_i = int phi and c_i = int q phi / m_i (eqs. (2), (3), Section 2.2).

    Empty cells keep mass 0 and the nearest point of S as their centroid.
    """
    origin, q, weight = _fan(batch, subdivision(density, batch))
    mass_density = weight * density.phi(q)
    mass = mass_density.sum(axis=(1, 2))
    empty = batch.empty
    # Moment about the cell's first vertex: cells far from the origin keep their digits.
    moment = np.einsum("klp,klpc->kc", mass_density, q - origin)
    centroid = as_complex(origin[:, 0, 0] + moment / np.where(empty, 1.0, mass)[:, None])
    return CellBatch(
        owners=batch.owners,
        start=batch.start,
        end=batch.end,
        labels=batch.labels,
        present=batch.present,
        mass=np.where(empty, 0.0, mass),
        centroid=np.where(empty, batch.centroid, centroid),
    )


def jacobian_blocks(
    density: Density, batch: CellBatch, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """dc/dp blocks of a weighed batch, eqs. (6) and (7) (Section 2.3) with phi.

    off (K, L, 2, 2): -int_{dV_ij} (q - c_i)(q - p_j)^T phi / (m_i |p_i - p_j|) for the
    edge on line l shared with robot j = labels[k, l], zero elsewhere; diagonal (K, 2, 2):
    the sum over j of the same integrals with p_i in place of p_j, plus sign. Empty cells
    get zero blocks (as covswarm.tvd.coverage.jacobian_blocks).
    """
    q, ds, lines = _edges(batch, subdivision(density, batch))
    labels, shared = batch.labels[:, :lines], batch.shared[:, :lines]
    me = points[batch.owners]
    others = points[np.maximum(labels, 0)]
    separation = np.linalg.norm(others - me[:, None, :], axis=-1)
    scale = np.where(
        shared, 1.0 / (np.where(shared, separation, 1.0) * np.maximum(batch.mass, 1e-300)[:, None]),
        0.0,
    )  # fmt: skip
    weighted = (scale[..., None] * ds * density.phi(q))[..., None] * (
        q - as_vectors(batch.centroid)[:, None, None, :]
    )
    off = np.zeros((len(batch.owners), batch.labels.shape[1], 2, 2))
    off[:, :lines] = -np.einsum("klgc,klgd->klcd", weighted, q - others[:, :, None, :])
    diagonal = np.einsum("klgc,klgd->kcd", weighted, q - me[:, None, None, :])
    return off, diagonal


def centroid_rates(
    density: Density, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
) -> np.ndarray:
    """dc_i/dt of Proposition 1 (Section 3, eq. (9)) for a weighed batch, (K,) complex: both terms.

    (1/m_i) int_{V_i} (q - c_i) dphi/dt + (1/m_i) int_{dS_i} (q - c_i) phi nu, with nu the
    outward normal speed of S, linear along each edge of S. An empty cell gets the velocity
    of its nearest point of S.
    """
    pieces = subdivision(density, batch)
    centroid = as_vectors(batch.centroid)[:, None, None, :]
    _, q, weight = _fan(batch, pieces)
    inner = np.einsum("klp,klpc->kc", weight * density.rate(q), q - centroid)

    q, ds, lines = _edges(batch, pieces)
    boundary = batch.boundary[:, :lines]
    edge = np.where(boundary, ~batch.labels[:, :lines], 0)[..., None]
    nu = domain.speed_offset[edge] + (domain.speed_gradient[edge].conj() * as_complex(q)).real
    f = np.where(boundary[..., None], ds * density.phi(q) * nu, 0.0)
    moving = np.einsum("klg,klgc->kc", f, q - centroid)

    rates = (inner + moving) / np.where(batch.empty, 1.0, batch.mass)[:, None]
    for i in np.flatnonzero(batch.empty):
        rates[i] = nearest_point_derivatives(domain, points[batch.owners[i]])[2]
    return as_complex(rates)
