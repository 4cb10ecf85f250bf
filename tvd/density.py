"""Time-varying density phi(q, t): Gaussian bumps on a uniform floor, and its cell integrals.

Model. Unnormalised bumps, so that a weight is the bump's peak height above the floor and
positivity is a one-line condition (every exp(...) lies in (0, 1]):

    phi(q, t) = floor + sum_b w_b(t) g_b(q, t),
    g_b(q, t) = exp(-1/2 (q - mu_b(t))^T Sigma_b(t)^-1 (q - mu_b(t))).

phi >= floor + sum of the negative weights, which must be > 0 (a bump may be a hole).

Time handling. A :class:`Density` is a snapshot at its own ``time``: the parameters hold
there and the rates (mu_dot, Sigma_dot, w_dot) are their time derivatives, so phi and
dphi/dt are exact at ``time`` and ``density.at(t)`` advances every parameter linearly to a
later snapshot (what a robot does between broadcasts). The coverage and control functions
take a snapshot already at the current time; they never see a clock. With x = q - mu and
P = Sigma^-1 (so dP/dt = -P Sigma_dot P),

    dphi/dt = sum_b g_b [ w_dot_b + w_b (mu_dot_b^T P_b x + 1/2 x^T P_b Sigma_dot_b P_b x) ].

Integrals over a CellBatch (covswarm.tvd.coverage), everything vectorised over (cells, edges,
quadrature points, bumps):

- m_i = int phi, c_i = int q phi / m_i and the density term of Proposition 1,
  int (q - c_i) dphi/dt, over a fan of triangles from the cell's first vertex, with a
  collapsed (Duffy) product Gauss-Legendre rule of TRIANGLE_ORDER^2 points per triangle;
- dc/dp (eqs. dcidpj, dcidpi) and the boundary term of Proposition 1 along each cell edge
  with EDGE_ORDER-point Gauss-Legendre; the outward speed of a boundary point varies
  linearly along its edge of S, as in covswarm.tvd.coverage.boundary_rates.

Narrow bumps. Both rules are applied on a uniform subdivision of every triangle and edge
into ``s`` pieces per side (s^2 triangles), s chosen per batch so that a piece is at most
RESOLUTION standard deviations of the narrowest bump long, s <= MAX_SUBDIVISION; the cost
is 64 s^2 points per fan triangle and 8 s per edge. Measured (tests/test_density.py,
``test_narrow_bump_accuracy``: one square cell of side L, a round bump of deviation sigma
off its centre, against the closed form with erf) relative error of mass and centroid:
1e-10 or better up to L / sigma = 24 (RESOLUTION = 6 gave 5e-8 there, hence 4); beyond,
with s capped, 1e-6 at L / sigma = 48, 4e-5 at 96, 2e-4 at 200.
dc/dp and dc/dt agree with central differences to 1e-9..5e-7 (the finite differences'
own error) on random cells, bumps and domain motions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from covswarm.tvd.coverage import (
    CellBatch,
    as_complex,
    as_vectors,
    cross,
    nearest_point_derivatives,
)
from covswarm.tvd.coverage import Domain as CoverageDomain

# Gauss-Legendre points per direction of the collapsed triangle rule (exact to degree
# 2 TRIANGLE_ORDER - 2) and per edge (exact to degree 2 EDGE_ORDER - 1).
TRIANGLE_ORDER = 8
EDGE_ORDER = 8
# Largest piece of a subdivided triangle or edge, in standard deviations of the narrowest
# bump, and the cap on pieces per side (the cost grows as its square).
RESOLUTION = 4.0
MAX_SUBDIVISION = 8
MAX_BUMPS = 16
# Relative asymmetry of a covariance (or its rate) accepted as rounding.
SYMMETRY_TOL = 1e-9

_BUMP_KEYS = ("mean", "cov", "weight", "mean_rate", "cov_rate", "weight_rate")


@dataclass(frozen=True, eq=False)
class Density:
    """phi at ``time``: floor > 0 and B bumps with their rates of change.

    means, mean_rates: (B, 2); covariances, covariance_rates: (B, 2, 2) symmetric, the
    covariances positive definite; weights, weight_rates: (B,). Raises ValueError naming
    every problem. Derived: precisions (B, 2, 2) = Sigma^-1 and sigma_min, the smallest
    standard deviation of any bump (inf without bumps).
    """

    floor: float
    means: np.ndarray
    covariances: np.ndarray
    weights: np.ndarray
    mean_rates: np.ndarray | None = None
    covariance_rates: np.ndarray | None = None
    weight_rates: np.ndarray | None = None
    time: float = 0.0
    precisions: np.ndarray = field(init=False, repr=False)
    sigma_min: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        means = _array(self.means, (-1, 2), "means")
        count = len(means)
        shapes = {
            "covariances": (count, 2, 2),
            "weights": (count,),
            "mean_rates": (count, 2),
            "covariance_rates": (count, 2, 2),
            "weight_rates": (count,),
        }
        values = {"means": means}
        for name, shape in shapes.items():
            given = getattr(self, name)
            values[name] = np.zeros(shape) if given is None else _array(given, shape, name)
        for name, value in values.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "floor", float(self.floor))
        object.__setattr__(self, "time", float(self.time))
        problems = _problems(self)
        if problems:
            raise ValueError("invalid density: " + "; ".join(problems))
        for name in ("covariances", "covariance_rates"):  # symmetric up to rounding: exactly
            matrix = getattr(self, name)
            object.__setattr__(self, name, 0.5 * (matrix + matrix.transpose(0, 2, 1)))
        object.__setattr__(self, "precisions", np.linalg.inv(self.covariances))
        smallest = np.linalg.eigvalsh(self.covariances)[:, 0] if count else np.array([np.inf])
        object.__setattr__(self, "sigma_min", float(np.sqrt(smallest.min())))

    # ---------------------------------------------------------------- evaluation

    def _bumps(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x = q - mu_b (..., B, 2) and g_b(q) (..., B) for points q (..., 2)."""
        x = q[..., None, :] - self.means
        px = np.einsum("bij,...bj->...bi", self.precisions, x)
        return x, np.exp(-0.5 * np.sum(x * px, axis=-1))

    def phi(self, q: np.ndarray) -> np.ndarray:
        """phi(q, time) for points q (..., 2): (...)."""
        return self.floor + self._bumps(q)[1] @ self.weights

    def rate(self, q: np.ndarray) -> np.ndarray:
        """dphi/dt(q, time) for points q (..., 2): (...) (module docstring)."""
        x, g = self._bumps(q)
        px = np.einsum("bij,...bj->...bi", self.precisions, x)
        drift = np.sum(px * self.mean_rates, axis=-1)
        spread = 0.5 * np.einsum("...bi,bij,...bj->...b", px, self.covariance_rates, px)
        return np.sum(g * (self.weight_rates + self.weights * (drift + spread)), axis=-1)

    def at(self, t: float) -> Density:
        """The snapshot at time t, every parameter advanced linearly; ValueError if invalid."""
        step = float(t) - self.time
        return Density(
            floor=self.floor,
            means=self.means + step * self.mean_rates,
            covariances=self.covariances + step * self.covariance_rates,
            weights=self.weights + step * self.weight_rates,
            mean_rates=self.mean_rates,
            covariance_rates=self.covariance_rates,
            weight_rates=self.weight_rates,
            time=float(t),
        )

    def frozen(self) -> Density:
        """This snapshot with every rate zero: a density that holds still."""
        return Density(self.floor, self.means, self.covariances, self.weights, time=self.time)

    # ---------------------------------------------------------------- wire form

    def to_dict(self) -> dict[str, Any]:
        """Plain data (floats and lists) for msgpack / TOML; ``from_dict`` reads it back."""
        bumps = [
            {
                "mean": self.means[b].tolist(),
                "cov": self.covariances[b].tolist(),
                "weight": float(self.weights[b]),
                "mean_rate": self.mean_rates[b].tolist(),
                "cov_rate": self.covariance_rates[b].tolist(),
                "weight_rate": float(self.weight_rates[b]),
            }
            for b in range(len(self.weights))
        ]
        return {"t": self.time, "floor": self.floor, "bumps": bumps}

    @classmethod
    def from_dict(cls, data: Any) -> Density:
        """Inverse of ``to_dict``; rates and "t" may be left out (0). ValueError if malformed."""
        if not isinstance(data, dict):
            raise ValueError(f"density: expected a map, got {type(data).__name__}")
        unknown = set(data) - {"t", "floor", "bumps"}
        if unknown or "floor" not in data:
            raise ValueError(f"density: need 'floor' (and 'bumps', 't'), unknown {sorted(unknown)}")
        bumps = data.get("bumps", [])
        if not isinstance(bumps, (list, tuple)) or len(bumps) > MAX_BUMPS:
            raise ValueError(f"density: 'bumps' must be a list of at most {MAX_BUMPS} maps")
        columns: dict[str, list[Any]] = {key: [] for key in _BUMP_KEYS}
        for i, bump in enumerate(bumps):
            if not isinstance(bump, dict) or set(bump) - set(_BUMP_KEYS):
                raise ValueError(f"density: bump {i} must be a map with keys from {_BUMP_KEYS}")
            if not {"mean", "cov", "weight"} <= set(bump):
                raise ValueError(f"density: bump {i} needs 'mean', 'cov' and 'weight'")
            zeros = {"mean_rate": [0.0, 0.0], "cov_rate": [[0.0, 0.0], [0.0, 0.0]]}
            for key in _BUMP_KEYS:
                columns[key].append(bump.get(key, zeros.get(key, 0.0)))
        return cls(
            floor=_number(data["floor"], "floor"),
            means=np.array(columns["mean"], dtype=float).reshape(-1, 2),
            covariances=np.array(columns["cov"], dtype=float).reshape(-1, 2, 2),
            weights=np.array(columns["weight"], dtype=float),
            mean_rates=np.array(columns["mean_rate"], dtype=float).reshape(-1, 2),
            covariance_rates=np.array(columns["cov_rate"], dtype=float).reshape(-1, 2, 2),
            weight_rates=np.array(columns["weight_rate"], dtype=float),
            time=_number(data.get("t", 0.0), "t"),
        )

    # ------------------------------------------- covswarm.tvd.coverage's DensityModel protocol

    def weigh(self, batch: CellBatch) -> CellBatch:
        return weigh(self, batch)

    def jacobian_blocks(
        self, batch: CellBatch, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return jacobian_blocks(self, batch, points)

    def boundary_rates(
        self, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
    ) -> np.ndarray:
        return centroid_rates(self, batch, points, domain)


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"density: {name} must be a number, got {value!r}")
    return float(value)


def _array(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        return np.array(value, dtype=np.float64).reshape(shape)
    except (TypeError, ValueError):
        raise ValueError(f"invalid density: {name} must be numbers of shape {shape}") from None


def _problems(density: Density) -> list[str]:
    """Why ``density`` is invalid (empty list when it is valid)."""
    problems = []
    if len(density.weights) > MAX_BUMPS:
        problems.append(f"{len(density.weights)} bumps, at most {MAX_BUMPS}")
    arrays = ("means", "covariances", "weights", "mean_rates", "covariance_rates", "weight_rates")
    for name in arrays:
        if not np.all(np.isfinite(getattr(density, name))):
            problems.append(f"{name} contain NaN or inf")
    if not math.isfinite(density.floor) or not math.isfinite(density.time):
        problems.append("floor and time must be finite")
    if problems:
        return problems
    lowest = density.floor + float(np.minimum(density.weights, 0.0).sum())
    if not lowest > 0.0:
        problems.append(
            f"phi can reach {lowest:g} <= 0: need floor > 0 and floor + negative weights > 0"
        )
    for name in ("covariances", "covariance_rates"):
        matrix = getattr(density, name)
        asymmetry = np.abs(matrix[:, 0, 1] - matrix[:, 1, 0])
        size = np.abs(matrix).max(axis=(1, 2), initial=0.0)
        bad = np.flatnonzero(asymmetry > SYMMETRY_TOL * np.maximum(size, 1e-300))
        if len(bad):
            problems.append(f"{name} of bumps {bad.tolist()} not symmetric")
    if len(density.weights):
        # Cholesky-free test of a symmetric 2x2: positive trace and determinant.
        cov = density.covariances
        det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
        bad = np.flatnonzero((det <= 0.0) | (cov[:, 0, 0] <= 0.0))
        if len(bad):
            problems.append(f"covariances of bumps {bad.tolist()} not positive definite")
    return problems


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
    """``batch`` with m_i = int phi and c_i = int q phi / m_i (eq. eqcenterOfMass).

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
    """dc/dp blocks of a weighed batch, eqs. (dcidpj) and (dcidpi) with phi.

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
    """dc_i/dt of Proposition 1 (eq. dcidt2) for a weighed batch, (K,) complex: both terms.

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


@dataclass(frozen=True, eq=False)
class DensityPath:
    """A mission's exact density law: ``base`` at t = 0, each bump also turning.

    Bump b at time t: mean mu + t mu_dot, weight w + t w_dot, covariance
    R(omega_b t) (Sigma + t Sigma_dot) R(omega_b t)^T with turn_rates omega_b (B,) in rad/s,
    so an elongated bump can turn for ever and stay positive definite. ``self(t)`` is the
    snapshot at t with the exact rates (what the coordinator broadcasts).
    """

    base: Density
    turn_rates: np.ndarray

    def __post_init__(self) -> None:
        rates = _array(self.turn_rates, (len(self.base.weights),), "turn_rates")
        if not np.all(np.isfinite(rates)):
            raise ValueError("invalid density: turn_rates contain NaN or inf")
        object.__setattr__(self, "turn_rates", rates)

    def __call__(self, t: float) -> Density:
        base, t = self.base, float(t)
        angle = self.turn_rates * t
        cos, sin = np.cos(angle), np.sin(angle)
        rotation = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)
        body = base.covariances + t * base.covariance_rates
        # d/dt (R B R^T) = R (B_dot + omega (J B - B J)) R^T, J the +90 degree rotation.
        turn = np.array([[0.0, -1.0], [1.0, 0.0]])
        body_rate = base.covariance_rates + self.turn_rates[:, None, None] * (
            turn @ body - body @ turn
        )
        spin = rotation.transpose(0, 2, 1)
        return Density(
            floor=base.floor,
            means=base.means + t * base.mean_rates,
            covariances=rotation @ body @ spin,
            weights=base.weights + t * base.weight_rates,
            mean_rates=base.mean_rates,
            covariance_rates=rotation @ body_rate @ spin,
            weight_rates=base.weight_rates,
            time=t,
        )

    @classmethod
    def from_table(cls, table: Any) -> DensityPath:
        """From a TOML ``[density]`` table: Density.from_dict keys, bumps may add turn_rate."""
        if not isinstance(table, dict) or "t" in table:
            raise ValueError("[density] must be a table of floor and bumps (no 't': t = 0)")
        bumps = table.get("bumps", [])
        if not isinstance(bumps, list) or not all(isinstance(b, dict) for b in bumps):
            raise ValueError("[density] bumps must be an array of tables ([[density.bumps]])")
        turns = [_number(b.get("turn_rate", 0.0), "turn_rate") for b in bumps]
        plain = [{k: v for k, v in b.items() if k != "turn_rate"} for b in bumps]
        return cls(Density.from_dict({**table, "bumps": plain}), np.array(turns))

    def to_table(self) -> dict[str, Any]:
        """Inverse of ``from_table`` (plain data)."""
        table = self.base.to_dict()
        del table["t"]
        for bump, turn in zip(table["bumps"], self.turn_rates.tolist(), strict=True):
            bump["turn_rate"] = turn
        return table
