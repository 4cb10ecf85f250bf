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

Integrals over a CellBatch (covswarm.tvd.coverage), vectorised over (cells, edges, bumps),
in closed form (the section "integrals" below): each bump is whitened (y = W (q - mu),
W^T W = Sigma^-1), which makes it exp(-|y|^2 / 2); by the divergence theorem its integral
over a cell and its moments of order 1 to 3 become sums over the cell's edges of erf and
exp (and, for the zeroth, Owen's T function of the bivariate normal law):

- m_i = int phi and c_i = int q phi / m_i;
- the density term of Proposition 1, int (q - c_i) dphi/dt, from the moments up to order 3
  (dphi/dt is g times a quadratic in y);
- dc/dp (eqs. (6), (7) of Section 2.3) and the boundary term of Proposition 1: along an edge, a
  polynomial of degree <= 2 times a one-dimensional Gaussian (erf and exp again; the
  outward speed of a boundary point varies linearly along its edge of S, as in
  covswarm.tvd.coverage.boundary_rates).

No quadrature and no subdivision: the cost does not depend on the cell's size compared
with the bumps. Where a cell is much smaller than a bump (whitened size below SMALL_CELL)
the edge sums cancel, and that (cell, bump) pair uses a Gauss rule on the cell instead,
whose order follows from an error estimate (RULE_TOL). A bump that contributes less than
SKIP times the floor to every cell of a batch is left out of it.

Accuracy contract (tests/test_density.py, tests/test_density_accuracy.py): for any cell
size relative to the bumps (cells from 1e-4 to 1e4 deviations wide) and any position (a
cell 8 deviations out in a bump's tail, the floor 1e-12 of its peak), masses within 1e-6
relative and centroids within 1e-6 of the cell size of an independent reference (scipy
dblquad over shapely-clipped cells, the closed form of a Gaussian over a square, the first
quadrature where it is exact), dc/dp within 1e-6 (it is dimensionless) and dc/dt within
1e-6 of the larger of its size and the speeds of S's vertices and of the bumps' means, of
central finite differences while the domain translates, scales and rotates and the bumps
move, grow and turn. Measured: 1e-12 or better against the references in the ordinary
cases, 3.5e-9 of the cell at worst (a cell 0.15 deviations wide 6 deviations out, floor
1e-12), the finite differences' own error (1e-8) against them.

Far from a bump the closed forms avoid the O(1) terms that would swamp a tiny tail: the
angle a cell subtends at the mean is taken as 2 pi or 0 exactly unless the mean is on its
boundary, and Owen's T near saturation is rewritten so that its constant cancels exactly
(``_owens_difference``).
The first implementation, an 8x8 Gauss-Legendre rule on subdivided triangles, is kept as
the tests' reference (tests/density_reference.py).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from functools import cache, cached_property
from typing import Any

import numpy as np
from scipy.special import erf, erfc, owens_t

from covswarm.tvd.coverage import CellBatch, CoverageDomain, as_complex
from covswarm.tvd.coverage import boundary_rates as uniform_boundary_rates

MAX_BUMPS = 16
# Relative asymmetry of a covariance (or its rate) accepted as rounding.
SYMMETRY_TOL = 1e-9

# A bump's keys in Density.to_dict / from_dict, and the form of each value.
BUMP_KEYS = ("mean", "cov", "weight", "mean_rate", "cov_rate", "weight_rate")
_BUMP_SHAPES = {"mean": (2,), "cov": (2, 2), "weight": (), "mean_rate": (2,), "cov_rate": (2, 2)}
_FORMS = {(): "a number", (2,): "[x, y]", (2, 2): "[[a, b], [c, d]]"}


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
    _memo: list = field(init=False, repr=False, default_factory=list)

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

    # Derived on first use: a robot makes a snapshot every tick (``at``) and may not need all.

    @cached_property
    def precisions(self) -> np.ndarray:
        """Sigma^-1 of every bump, (B, 2, 2)."""
        return np.linalg.inv(self.covariances)

    @cached_property
    def sigma_min(self) -> float:
        """The smallest standard deviation of any bump (inf without bumps)."""
        return float(self.bumps.deviation.min(initial=np.inf))

    @cached_property
    def bumps(self) -> _Bumps:
        """The bumps as the closed-form integrals use them."""
        return _Bumps.of(self)

    # ---------------------------------------------------------------- evaluation

    def _bumps(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x = q - mu_b (..., B, 2) and g_b(q) (..., B) for points q (..., 2)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape[-1:] != (2,):
            raise ValueError(f"points must have shape (..., 2), got {q.shape}")
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
        """The snapshot at time t, every parameter advanced linearly; ValueError if invalid.

        A robot makes one per tick, so the advance of a valid snapshot is checked for what
        it can break (finiteness, positive definite covariances, phi > 0: symmetric
        matrices advanced by symmetric rates stay exactly symmetric) and built without the
        full validation; anything else takes the full one, which names the problems.
        """
        time = float(t)
        step = time - self.time
        means = self.means + step * self.mean_rates
        covariances = self.covariances + step * self.covariance_rates
        weights = self.weights + step * self.weight_rates
        if not _still_valid(self.floor, means, covariances, weights):
            return Density(
                self.floor, means, covariances, weights, self.mean_rates,
                self.covariance_rates, self.weight_rates, time,
            )  # fmt: skip
        advanced = object.__new__(Density)
        fields = {
            "floor": self.floor,
            "means": means,
            "covariances": covariances,
            "weights": weights,
            "mean_rates": self.mean_rates,
            "covariance_rates": self.covariance_rates,
            "weight_rates": self.weight_rates,
            "time": time,
            "_memo": [],
        }
        for name, value in fields.items():
            object.__setattr__(advanced, name, value)
        return advanced

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
        if unknown:
            raise ValueError(
                f"density: unknown keys {sorted(map(str, unknown))}; the keys are floor, bumps, t"
            )
        if "floor" not in data:
            raise ValueError("density: needs 'floor' (phi's value far from every bump)")
        bumps = data.get("bumps", [])
        if not isinstance(bumps, (list, tuple)) or len(bumps) > MAX_BUMPS:
            raise ValueError(f"density: 'bumps' must be a list of at most {MAX_BUMPS} maps")
        columns: dict[str, list[Any]] = {key: [] for key in BUMP_KEYS}
        for i, bump in enumerate(bumps):
            if not isinstance(bump, dict):
                raise ValueError(f"density: bump {i} must be a map, got {bump!r}")
            if unknown := set(bump) - set(BUMP_KEYS):
                raise ValueError(
                    f"density: bump {i}: unknown keys {sorted(map(str, unknown))}; "
                    f"the keys are {', '.join(BUMP_KEYS)}"
                )
            if missing := [key for key in ("mean", "cov", "weight") if key not in bump]:
                raise ValueError(f"density: bump {i} needs {', '.join(missing)}")
            for key in BUMP_KEYS:
                shape = _BUMP_SHAPES.get(key, ())
                value = bump.get(key, np.zeros(shape).tolist() if shape else 0.0)
                columns[key].append(_numbers(value, shape, f"bump {i} {key}"))
        return cls(  # the constructor's _array makes them arrays of their shapes
            floor=_numbers(data["floor"], (), "floor"),
            means=columns["mean"],
            covariances=columns["cov"],
            weights=columns["weight"],
            mean_rates=columns["mean_rate"],
            covariance_rates=columns["cov_rate"],
            weight_rates=columns["weight_rate"],
            time=_numbers(data.get("t", 0.0), (), "t"),
        )

    # ------------------------------------------- covswarm.tvd.coverage's DensityModel protocol

    def weigh(self, batch: CellBatch) -> CellBatch:
        return weigh(self, batch)

    def jacobian_blocks(
        self, batch: CellBatch, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return jacobian_blocks(self, batch, points)

    def jacobian_times(
        self, batch: CellBatch, points: np.ndarray, own: np.ndarray, others: np.ndarray
    ) -> np.ndarray:
        return jacobian_times(self, batch, points, own, others)

    def boundary_rates(
        self, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
    ) -> np.ndarray:
        return centroid_rates(self, batch, points, domain)


def _numbers(value: Any, shape: tuple[int, ...], name: str) -> Any:
    """``value`` as floats nested in lists of exactly ``shape`` (() a number, (2,) a point,
    (2, 2) a matrix), else ValueError naming ``name`` and the form expected: a flat or too
    deeply nested matrix, a string or a boolean is refused, not reshaped or converted."""
    if isinstance(value, np.ndarray):
        value = value.tolist()

    def walk(item: Any, dims: tuple[int, ...]) -> Any:
        if not dims:
            if isinstance(item, bool) or not isinstance(item, numbers.Real):
                raise ValueError(f"density: {name} must be {_FORMS[shape]}, got {value!r}")
            return float(item)
        if not isinstance(item, (list, tuple)) or len(item) != dims[0]:
            raise ValueError(f"density: {name} must be {_FORMS[shape]}, got {value!r}")
        return [walk(part, dims[1:]) for part in item]

    return walk(value, shape)


def _array(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``value`` as float64 of exactly ``shape`` (-1: any length), never reshaped: a (2, B)
    array of means read as (B, 2) would scramble x and y. An empty value is no bump."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is not None and array.size == 0:
        return array.reshape([0 if n == -1 else n for n in shape])
    if (
        array is None
        or array.ndim != len(shape)
        or any(n not in (-1, m) for n, m in zip(shape, array.shape, strict=True))
    ):
        given = "not numbers" if array is None else f"shape {array.shape}"
        expected = ", ".join("B" if n == -1 else str(n) for n in shape) + "," * (len(shape) == 1)
        raise ValueError(f"invalid density: {name} must be numbers of shape ({expected}), {given}")
    return array


def _still_valid(
    floor: float, means: np.ndarray, covariances: np.ndarray, weights: np.ndarray
) -> bool:
    """Whether a valid density's linear advance to these parameters is valid (``at``)."""
    finite = np.isfinite(means).all() and np.isfinite(covariances).all()
    if not (finite and np.isfinite(weights).all()):
        return False
    lowest = floor + float(weights[weights < 0.0].sum())
    det = covariances[:, 0, 0] * covariances[:, 1, 1] - covariances[:, 0, 1] ** 2
    return lowest > 0.0 and bool((det > 0.0).all() and (covariances[:, 0, 0] > 0.0).all())


def _problems(density: Density) -> list[str]:
    """Why ``density`` is invalid (empty list when it is valid). Each check runs on every
    array at once and names the culprits only when it fails: a robot validates a snapshot
    every tick."""
    problems = []
    if len(density.weights) > MAX_BUMPS:
        problems.append(f"{len(density.weights)} bumps, at most {MAX_BUMPS}")
    names = ("means", "covariances", "weights", "mean_rates", "covariance_rates", "weight_rates")
    arrays = [getattr(density, name) for name in names]
    if not np.isfinite(np.concatenate([array.ravel() for array in arrays])).all():
        problems += [
            f"{name} contain NaN or inf"
            for name, array in zip(names, arrays, strict=True)
            if not np.isfinite(array).all()
        ]
    if not math.isfinite(density.floor) or not math.isfinite(density.time):
        problems.append("floor and time must be finite")
    if problems:
        return problems
    lowest = density.floor + float(np.minimum(density.weights, 0.0).sum())
    if not lowest > 0.0:
        problems.append(
            f"phi can reach {lowest:g} <= 0: need floor > 0 and floor + negative weights > 0"
        )
    matrices = np.stack((density.covariances, density.covariance_rates))  # (2, B, 2, 2)
    asymmetry = np.abs(matrices[..., 0, 1] - matrices[..., 1, 0])
    size = np.abs(matrices).max(axis=(2, 3), initial=0.0)
    asymmetric = asymmetry > SYMMETRY_TOL * np.maximum(size, 1e-300)
    if asymmetric.any():
        for name, bad in zip(("covariances", "covariance_rates"), asymmetric, strict=True):
            if bad.any():
                problems.append(f"{name} of bumps {np.flatnonzero(bad).tolist()} not symmetric")
    # Cholesky-free test of a symmetric 2x2: positive trace and determinant.
    cov = density.covariances
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        diagonal = cov[:, 0, 0] * cov[:, 1, 1]
        det = diagonal - cov[:, 0, 1] * cov[:, 1, 0]
    # A positive diagonal whose product underflows to 0 is no singular matrix.
    underflow = (diagonal == 0.0) & (cov[:, 0, 0] > 0.0) & (cov[:, 1, 1] > 0.0)
    beyond = ~np.isfinite(det) | underflow
    if beyond.any():
        bad = np.flatnonzero(beyond).tolist()
        problems.append(f"covariances of bumps {bad} too large or too small (their determinants "
                        "overflow or underflow)")  # fmt: skip
    indefinite = ~beyond & ((det <= 0.0) | (cov[:, 0, 0] <= 0.0))
    if indefinite.any():
        bad = np.flatnonzero(indefinite).tolist()
        problems.append(f"covariances of bumps {bad} not positive definite")
    return problems


# ---------------------------------------------------------------------------- integrals
#
# Closed forms (the module docstring says what they serve). After whitening a bump,
# y = W (q - mu) with W^T W = Sigma^-1 (dq = det L dy, L = W^-1), its Gaussian is
# G(y) = exp(-|y|^2 / 2). On a cell edge in the whitened plane, y = F + t u: u the unit
# direction, F = h n the foot of the perpendicular from the mean (n = -i u the outward
# normal, h the signed distance of the mean, > 0 on the cell's side), t in [t_a, t_b], so
# G = exp(-h^2 / 2) exp(-t^2 / 2) and E_k = int t^k G dt (k = 0, 1, 2) are erf and exp.
# Over the cell, by the divergence theorem with grad G = -y G:
#
#   m0 = int G dy              the signed triangles (mean, y_a, y_b): atan and Owen's T,
#   m1 = int y G               = -sum n E0,
#   m2 = int y y^T G           = m0 I - sum (F E0 + u E1) n^T,
#   m3_jkl = int y_j y_k y_l G = d_jl m1_k + d_kl m1_j - sum n_l (F F^T E0 + (F u^T + u F^T) E1
#                                + u u^T E2)_jk.
#
# Rounding: the sums over edges cancel when a cell is much smaller than a bump; (cell, bump)
# pairs whose whitened size is below SMALL_CELL take m0..m3 and E0..E2 from a Gauss rule on
# the cell instead, accurate there because the bump is smooth across the cell. Far out in a
# bump's tail, m0 avoids O(1) terms (``_closed_moments``, ``_owens_difference``).

SQRT_HALF = math.sqrt(0.5)
SQRT_HALF_PI = math.sqrt(0.5 * math.pi)
# Whitened cell size (the largest whitened distance from its first vertex to another) below
# which a (cell, bump) pair uses the Gauss rule (measured: the closed forms hold 1e-9 down to
# 0.1, 1e-5 at 0.01).
SMALL_CELL = 0.1
# A bump is left out of a batch when it adds less than SKIP times the floor to every cell of
# it, phi and dphi/dt alike (rates per second; ``_bump_row``): far below the rounding of the
# floor's part.
SKIP = 1e-13
# The small-cell rule: G varies across such a cell by a factor exp(+-v), v = size (reach +
# size), so a Taylor polynomial of degree k is within e^v v^(k+1) / (k+1)! of it, relative;
# k is the smallest degree under RULE_TOL, and the rule is exact to degree k + 3 (the
# moments multiply G by polynomials of degree up to 3).
RULE_TOL = 1e-12
MAX_RULE_ORDER = 12


def _bump_row(
    a: float,
    b: float,
    _: float,
    c: float,
    s00: float,
    s01: float,
    __: float,
    s11: float,
    mx: float,
    my: float,
    weight: float,
    weight_rate: float,
    floor: float,
) -> tuple[complex, complex, complex, complex, float, float, complex, float, complex, float]:
    """One bump's row of _Bumps from Sigma = [[a, b], [b, c]], Sigma_dot = [[s00, s01],
    [s01, s11]], mu_dot = (mx, my), w, w_dot and the floor. Cholesky Sigma = L L^T,
    L = [[l00, 0], [l10, l11]], W = L^-1 = [[w00, 0], [w10, w11]]; a real map [[p, q],
    [r, s]] is the complex pair ((p + s) + i (r - q)) / 2, ((p - s) + i (r + q)) / 2;
    M = W Sigma_dot W^T / 2.

    The reach: at a whitened distance r, g (|w_dot| + |w| (1 + |a| r + |M| r^2)) <=
    A (1 + r^2) exp(-r^2 / 2) <= 2 A exp(-r^2 / 4), A = |w_dot| + |w| (1 + |a| + |M|),
    which is below SKIP times the floor beyond r = 2 sqrt(ln(2 A / (SKIP floor)))."""
    l00 = math.sqrt(a)
    l10 = b / l00
    l11 = math.sqrt(c - l10 * l10)
    w00, w11 = 1.0 / l00, 1.0 / l11
    w10 = -l10 * w00 * w11
    m00 = 0.5 * w00 * w00 * s00
    m01 = 0.5 * w00 * (s00 * w10 + s01 * w11)
    m11 = 0.5 * (w10 * (w10 * s00 + w11 * s01) + w11 * (w10 * s01 + w11 * s11))
    largest = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)  # eigenvalues of Sigma
    drift = complex(w00 * mx, w10 * mx + w11 * my)
    spread, twist = 0.5 * (m00 + m11), complex(0.5 * (m00 - m11), m01)
    amplitude = abs(weight_rate) + abs(weight) * (1.0 + abs(drift) + abs(spread) + abs(twist))
    return (
        complex(0.5 * (w00 + w11), 0.5 * w10),
        complex(0.5 * (w00 - w11), 0.5 * w10),
        complex(0.5 * (l00 + l11), 0.5 * l10),
        complex(0.5 * (l00 - l11), 0.5 * l10),
        l00 * l11,
        math.sqrt((a * c - b * b) / largest),  # the smallest deviation, without cancellation
        drift,
        spread,
        twist,
        2.0 * math.sqrt(math.log(max(2.0 * amplitude / (SKIP * floor), 1.0))),
    )


@dataclass(frozen=True)
class _Bumps:
    """The bumps as the closed forms use them, (B,) arrays; plane vectors complex.

    centers mu; white, lower: W and L = W^-1 as complex maps (alpha, beta), A z = alpha z +
    beta conj(z), with Sigma = L L^T (Cholesky); scale det L; deviation the smallest standard
    deviation; weights, weight_rates w, w_dot; drift W mu_dot; spread, twist: the complex map
    of M = W Sigma_dot W^T / 2 (symmetric: spread real, the half trace); reach the whitened
    distance beyond which the bump is negligible (``_bump_row``).
    """

    centers: np.ndarray
    white: tuple[np.ndarray, np.ndarray]
    lower: tuple[np.ndarray, np.ndarray]
    scale: np.ndarray
    deviation: np.ndarray
    weights: np.ndarray
    weight_rates: np.ndarray
    drift: np.ndarray
    spread: np.ndarray
    twist: np.ndarray
    reach: np.ndarray

    @classmethod
    def of(cls, density: Density) -> _Bumps:
        """From a validated density, in closed form for 2 x 2 matrices, bump by bump in
        Python floats: this runs once per snapshot, i.e. per robot per tick, for a few
        bumps, where numpy's per-call cost would dominate."""
        rows = [
            _bump_row(*cov, *rate, *mean_rate, weight, weight_rate, density.floor)
            for cov, rate, mean_rate, weight, weight_rate in zip(
                density.covariances.reshape(-1, 4).tolist(),
                density.covariance_rates.reshape(-1, 4).tolist(),
                density.mean_rates.tolist(),
                density.weights.tolist(),
                density.weight_rates.tolist(),
                strict=True,
            )
        ]
        columns = np.array(rows, dtype=np.complex128).reshape(-1, 10).T
        white_a, white_b, lower_a, lower_b, scale, deviation, drift, spread, twist, reach = columns
        return cls(
            centers=as_complex(density.means),
            white=(white_a, white_b),
            lower=(lower_a, lower_b),
            scale=scale.real,
            deviation=deviation.real,
            weights=density.weights,
            weight_rates=density.weight_rates,
            drift=drift,
            spread=spread.real,
            twist=twist,
            reach=reach.real,
        )

    def take(self, kept: np.ndarray) -> _Bumps:
        """The bumps ``kept`` (indices)."""
        return _Bumps(
            **{
                name: tuple(part[kept] for part in value)
                if isinstance(value, tuple)
                else value[kept]
                for name, value in vars(self).items()
            }
        )

    def whiten(self, q: np.ndarray) -> np.ndarray:
        """W (q - mu) for plane points q (...) complex: (..., B)."""
        x = q[..., None] - self.centers
        return self.white[0] * x + self.white[1] * x.conj()

    def unwhiten(self, y: np.ndarray) -> np.ndarray:
        """L y for whitened vectors y (..., B) complex."""
        return self.lower[0] * y + self.lower[1] * y.conj()


@dataclass(frozen=True)
class _Edges:
    """Every (cell, line, bump) edge in its bump's whitened plane, (K, L, B) arrays.

    y_a: the edge's start, whitened (complex); h: signed distance of the mean from the
    edge's line; u: unit direction (complex; 0 on absent lines); t_a, t_b: ends along u from
    the foot; e0, e1, e2: int (t - origin)^k G dt, about the foot (origin 0) in the closed
    forms and about the edge's start (origin t_a) where the Gauss rule is used, so that a
    short edge far from its foot keeps its digits.
    """

    y_a: np.ndarray
    h: np.ndarray
    u: np.ndarray
    t_a: np.ndarray
    t_b: np.ndarray
    e0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    origin: np.ndarray | float = 0.0


@dataclass(frozen=True)
class _Integrals:
    """A batch's integrals of each bump: what weigh, the dphi/dt term, dc/dp and the boundary
    term need, for the bumps that matter to it (``bumps``). (K, B) unless stated.

    m0 = int G dy, m1 = int y G (complex), m2_a = m2 a (complex), m_m2 = M : m2,
    m3_m = m3 : M (complex), with a = drift, M the map (spread, twist); edges (K, L, B).
    """

    bumps: _Bumps
    edges: _Edges
    m0: np.ndarray
    m1: np.ndarray
    m2_a: np.ndarray
    m_m2: np.ndarray
    m3_m: np.ndarray

    def rows(self, count: int) -> _Integrals:
        """The first ``count`` cells."""
        if count == len(self.m0):
            return self
        edges = _Edges(
            **{
                name: value[:count] if np.ndim(value) else value
                for name, value in vars(self.edges).items()
            }
        )
        moments = {name: getattr(self, name)[:count] for name in _MOMENTS}
        return _Integrals(bumps=self.bumps, edges=edges, **moments)


_MOMENTS = ("m0", "m1", "m2_a", "m_m2", "m3_m")


def _integrals(density: Density, batch: CellBatch) -> _Integrals | None:
    """The bumps' integrals over ``batch``, None when no bump matters to it.

    weigh, then dc/dt and dc/dp, are called on the same cells (a weighed batch shares the
    edge arrays; a robot's own row is a prefix of its batch): the last result is kept and
    reused when the edges are the same values, checked here, not assumed (the same arrays,
    or views of their leading rows, else compared value by value).
    """
    memo = density._memo
    if memo:
        start, end, present, kept = memo[0]
        count, lines = batch.start.shape
        if batch.start is start or (
            count <= len(start)
            and lines == start.shape[1]
            and all(
                _leading_rows(mine, theirs) or np.array_equal(mine, theirs[:count])
                for mine, theirs in (
                    (batch.start, start),
                    (batch.end, end),
                    (batch.present, present),
                )
            )
        ):
            return None if kept is None else kept.rows(count)
    result = _compute_integrals(density.bumps, density.floor, batch)
    memo[:] = [(batch.start, batch.end, batch.present, result)]
    return result


def _leading_rows(view: np.ndarray, array: np.ndarray) -> bool:
    """Whether ``view`` is a slice of the leading rows of ``array`` (the same memory, as a
    robot's own row of its batch is): then it holds their values without comparing them."""
    return (
        view.base is not None
        and (view.base is array or view.base is array.base)
        and view.strides == array.strides
        and view.__array_interface__["data"][0] == array.__array_interface__["data"][0]
    )


def _trim(batch: CellBatch) -> int:
    """Number of leading lines that hold every present edge (the rest are padding)."""
    return max(int(batch.present.sum(axis=1).max(initial=0)), 1)


def _compute_integrals(bumps: _Bumps, floor: float, batch: CellBatch) -> _Integrals | None:
    if not len(bumps.weights):
        return None
    lines = _trim(batch)
    start, end = batch.start[:, :lines], batch.end[:, :lines]
    present = batch.present[:, :lines]
    first = start[:, :1]
    extent = np.where(present, np.abs(start - first), 0.0).max(axis=1)  # (K,)
    reach = np.abs(bumps.whiten(first[:, 0]))  # whitened distance to the first vertex
    # A lower bound on the whitened distance from the mean to the cell, against the bump's
    # reach (``_bump_row``).
    far = reach - extent[:, None] / bumps.deviation > bumps.reach  # (K, B)
    if far.any():
        kept = np.flatnonzero(~far.all(axis=0))
        if not len(kept):
            return None
        bumps, reach = bumps.take(kept), reach[:, kept]
    edges = _edge_moments(bumps, start, end, present)
    integrals = _closed_moments(bumps, edges)
    # The whitened extent itself (an elongated bump: the bound above can be far larger).
    size = np.where(present[..., None], np.abs(edges.y_a - edges.y_a[:, :1]), 0.0).max(axis=1)
    small = size < SMALL_CELL
    if small.any():
        order = _rule_order(float((size * (reach + size))[small].max()))
        integrals = _small_cells(bumps, batch, lines, integrals, small, order)
    return integrals


def _edge_moments(bumps: _Bumps, start: np.ndarray, end: np.ndarray, present: np.ndarray) -> _Edges:
    """The whitened geometry and E0..E2 of edges from ``start`` to ``end`` (K, L) complex."""
    y_a, y_b = bumps.whiten(start), bumps.whiten(end)
    step = y_b - y_a
    length = np.abs(step)
    u = np.divide(step, length, out=np.zeros_like(step), where=present[..., None])
    t_a = (u.conj() * y_a).real
    t_b = t_a + np.where(present[..., None], length, 0.0)
    h = (y_a.conj() * u).imag
    foot = np.exp(-0.5 * h * h)
    # erf(b) - erf(a) as erfc(a) - erfc(b) on the side where both are not large and positive.
    mirror = t_a + t_b < 0.0
    low, high = np.where(mirror, -t_b, t_a), np.where(mirror, -t_a, t_b)
    e0 = foot * SQRT_HALF_PI * (erfc(SQRT_HALF * low) - erfc(SQRT_HALF * high))
    g_a, g_b = np.exp(-0.5 * t_a * t_a), np.exp(-0.5 * t_b * t_b)
    e1 = foot * (g_a - g_b)
    e2 = foot * (t_a * g_a - t_b * g_b) + e0
    return _Edges(y_a=y_a, h=h, u=u, t_a=t_a, t_b=t_b, e0=e0, e1=e1, e2=e2)


def _owens_difference(h: np.ndarray, t_a: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    """T(h, t_b / h) - T(h, t_a / h) (Owen's T, h != 0) without cancellation.

    T(h, t / h) = sign(h) sign(t) T(g, |t| / g), g = |h|. Where |t| > g the value is close to
    T(g, inf), the same at both ends of an edge whose line passes near the mean while the
    edge is far from it: there T(g, a) = Q(g) / 2 + Q(|t|) / 2 - Q(g) Q(|t|) - T(|t|, 1 / a)
    (Q the normal tail), whose Q(g) / 2 cancels between the ends exactly, and every other
    term is as small as the edge's own share.
    """
    g = np.abs(h)
    ends = np.array((t_b, t_a))
    size = np.abs(ends)
    far = size > g
    tail_g = 0.5 * erfc(SQRT_HALF * g)
    tail_t = 0.5 * erfc(SQRT_HALF * size)
    owen = owens_t(np.where(far, size, g), np.where(far, g / np.where(far, size, 1.0), size / g))
    # Each end's T(g, |t| / g) - Q(g) / 2, signed by t.
    middle = 0.5 * erf(SQRT_HALF * g)  # 1/2 - Q(g), without cancellation for a small g
    sign = np.sign(ends)
    value = sign * np.where(far, tail_t * middle - owen, owen - 0.5 * tail_g)
    return np.sign(h) * (value[0] - value[1] + 0.5 * tail_g * (sign[0] - sign[1]))


def _closed_moments(bumps: _Bumps, edges: _Edges) -> _Integrals:
    """m0..m3 (contracted) of every (cell, bump) by the divergence theorem."""
    h, u, e0, e1, e2 = edges.h, edges.u, edges.e0, edges.e1, edges.e2
    n = -1j * u
    # m0: each edge's signed triangle from the mean is the difference of two right triangles
    # with legs h and t, of normal probability atan(t / h) / 2 pi - T(h, t / h). The atan
    # terms add up to the angle the cell subtends at the mean: 2 pi inside, 0 outside, taken
    # exactly, or a cell far from the mean would lose its tiny m0 to their O(1) rounding; only
    # a mean on the boundary (some h = 0, none < 0) needs their sum.
    on_line = h == 0.0  # a degenerate triangle
    safe = np.where(on_line, 1.0, h)
    tails = np.where(on_line, 0.0, _owens_difference(safe, edges.t_a, edges.t_b)).sum(axis=1)
    present = u != 0.0
    outside = ((h < 0.0) & present).any(axis=1)
    inside = ((h > 0.0) | ~present).all(axis=1)
    angle = 2.0 * math.pi * inside
    if not (inside | outside).all():
        turn = np.arctan(np.stack((edges.t_b, edges.t_a)) / safe)
        subtended = np.where(on_line, 0.0, turn[0] - turn[1]).sum(axis=1)
        angle = np.where(inside | outside, angle, subtended)
    m0 = angle - 2.0 * math.pi * tails
    m1 = -(n * e0).sum(axis=1)
    drift, spread, twist = bumps.drift, bumps.spread, bumps.twist
    turned = twist * (u.conj() ** 2)
    n_m_n = spread - turned.real  # n . M n
    u_m_n = (1j * turned).real  # u . M n
    # m2 a = m0 a - sum (h E0 n + E1 u)(n . a); M : m2 = tr(M) m0 - sum (h E0 nMn + E1 uMn);
    # m3 : M = M m1 + tr(M) m1 - sum [h n (h E0 nMn + E1 uMn) + u (h E1 nMn + E2 uMn)].
    along_n = h * e0 * n_m_n + e1 * u_m_n
    return _Integrals(
        bumps=bumps,
        edges=edges,
        m0=m0,
        m1=m1,
        m2_a=m0 * drift - ((h * e0 * n + e1 * u) * (n.conj() * drift).real).sum(axis=1),
        m_m2=2.0 * spread * m0 - along_n.sum(axis=1),
        m3_m=3.0 * spread * m1
        + twist * m1.conj()
        - (h * n * along_n + u * (h * e1 * n_m_n + e2 * u_m_n)).sum(axis=1),
    )


def _rule_order(variation: float) -> int:
    """Gauss-Legendre points per direction for a log-variation ``variation`` of G across the
    cell: the collapsed triangle rule with n points is exact to degree 2n - 2 >= k + 3."""
    degree = 0
    while math.exp(variation) * variation ** (degree + 1) / math.factorial(degree + 1) > RULE_TOL:
        degree += 1
    return min(math.ceil((degree + 5) / 2), MAX_RULE_ORDER)


@cache
def _gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1], (order,) each."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    return 0.5 * (nodes + 1.0), 0.5 * weights


@cache
def _triangle_rule(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Collapsed (Duffy) Gauss rule on the triangle (0, 0), (1, 0), (0, 1): coordinates a, b
    of q = v0 + a (v1 - v0) + b (v2 - v0) and weights summing to 1/2, (order^2,) each."""
    nodes, weights = _gauss_legendre(order)
    u, v = np.meshgrid(nodes, nodes, indexing="ij")
    weight = weights[:, None] * weights[None, :] * (1.0 - u)
    return u.ravel(), ((1.0 - u) * v).ravel(), weight.ravel()


def _small_cells(
    bumps: _Bumps,
    batch: CellBatch,
    lines: int,
    closed: _Integrals,
    small: np.ndarray,
    order: int,
) -> _Integrals:
    """``closed`` with the pairs ``small`` (K, B) integrated by an ``order`` Gauss rule: the
    cell as a fan of triangles from its first vertex, each edge in t."""
    start, end = batch.start[:, :lines], batch.end[:, :lines]
    present = batch.present[:, :lines]
    first = start[:, :1]
    a, b, weight = _triangle_rule(order)
    q = first[..., None] + a * (start - first)[..., None] + b * (end - first)[..., None]
    twice_area = np.where(present, ((start - first).conj() * (end - first)).imag, 0.0)
    y = bumps.whiten(q)  # (K, L, P, B)
    mass = (
        (twice_area[..., None] * weight)[..., None]
        / bumps.scale
        * np.exp(-0.5 * (y.real**2 + y.imag**2))
    )
    spread_y = bumps.spread * y + bumps.twist * y.conj()
    y_m_y = (y.conj() * spread_y).real
    y_a = (y.conj() * bumps.drift).real
    total = mass.sum(axis=(1, 2)), (mass * y).sum(axis=(1, 2))
    m0, m1 = total
    m2_a = (mass * y * y_a).sum(axis=(1, 2))
    m_m2 = (mass * y_m_y).sum(axis=(1, 2))
    m3_m = (mass * y * y_m_y).sum(axis=(1, 2))
    edges = closed.edges
    nodes, node_weights = _gauss_legendre(order)
    span = edges.t_b - edges.t_a
    s = span[..., None] * nodes  # t - t_a
    t = edges.t_a[..., None] + s
    g = (span[..., None] * node_weights) * np.exp(-0.5 * (edges.h[..., None] ** 2 + t * t))
    pair = small[:, None, :]
    rule_edges = _Edges(
        y_a=edges.y_a,
        h=edges.h,
        u=edges.u,
        t_a=edges.t_a,
        t_b=edges.t_b,
        e0=np.where(pair, g.sum(axis=-1), edges.e0),
        e1=np.where(pair, (g * s).sum(axis=-1), edges.e1),
        e2=np.where(pair, (g * s * s).sum(axis=-1), edges.e2),
        origin=np.where(pair, edges.t_a, 0.0),
    )
    return _Integrals(
        bumps=bumps,
        edges=rule_edges,
        m0=np.where(small, m0, closed.m0),
        m1=np.where(small, m1, closed.m1),
        m2_a=np.where(small, m2_a, closed.m2_a),
        m_m2=np.where(small, m_m2, closed.m_m2),
        m3_m=np.where(small, m3_m, closed.m3_m),
    )


# ---------------------------------------------------------------------------- DensityModel


def _area_centroid(batch: CellBatch) -> tuple[np.ndarray, np.ndarray]:
    """Area (K,) and geometric centroid (K,) complex of each cell (Section 4.2), about its
    first vertex so that a cell far from the origin keeps its digits; an empty cell keeps
    the batch's centroid (the nearest point of S)."""
    lines = _trim(batch)
    origin = batch.start[:, :1]
    present = batch.present[:, :lines]
    a = np.where(present, batch.start[:, :lines] - origin, 0.0)
    b = np.where(present, batch.end[:, :lines] - origin, 0.0)
    twice = (a.conj() * b).imag
    area = 0.5 * twice.sum(axis=1)
    solid = area > 0.0
    moment = (twice * (a + b)).sum(axis=1) / (6.0 * np.where(solid, area, 1.0))
    return np.where(solid, area, 0.0), np.where(solid, origin[:, 0] + moment, batch.centroid)


def weigh(density: Density, batch: CellBatch) -> CellBatch:
    """``batch`` with m_i = int phi and c_i = int q phi / m_i (eqs. (2), (3), Section 2.2).

    Empty cells keep mass 0 and the nearest point of S as their centroid.
    """
    area, middle = _area_centroid(batch)
    mass, centroid = density.floor * area, middle
    integrals = _integrals(density, batch)
    if integrals is not None:
        bumps = integrals.bumps
        weight = bumps.weights * bumps.scale
        mass = mass + (weight * integrals.m0).sum(axis=1)
        # First moment about the geometric centroid, where the floor's is zero.
        offset = bumps.centers - middle[:, None]
        moment = weight * (bumps.unwhiten(integrals.m1) + offset * integrals.m0)
        centroid = middle + moment.sum(axis=1) / np.where(area > 0.0, mass, 1.0)
    empty = area <= 0.0
    return CellBatch(
        owners=batch.owners,
        start=batch.start,
        end=batch.end,
        labels=batch.labels,
        present=batch.present,
        mass=np.where(empty, 0.0, mass),
        centroid=np.where(empty, batch.centroid, centroid),
    )


def _edge_lines(bumps: _Bumps, edges: _Edges) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each edge in the plane as q = foot + (t - origin) beta: foot (the point at t = origin),
    beta (K, L, B) complex and |beta| = ds / dt (K, L, B)."""
    foot = bumps.centers + bumps.unwhiten((edges.origin - 1j * edges.h) * edges.u)
    beta = bumps.unwhiten(edges.u)
    return foot, beta, np.abs(beta)


def _outer_blocks(plain: np.ndarray, twisted: np.ndarray) -> np.ndarray:
    """Sums of outer products a b^T of plane vectors as 2 x 2 blocks (..., 2, 2), from
    plain = sum a b and twisted = sum a conj(b) (complex products): a_x b_x is half the real
    part of their sum, a_y b_y half that of their difference, and so on."""
    blocks = np.empty((*plain.shape, 2, 2))
    blocks[..., 0, 0] = 0.5 * (plain.real + twisted.real)
    blocks[..., 0, 1] = 0.5 * (plain.imag - twisted.imag)
    blocks[..., 1, 0] = 0.5 * (plain.imag + twisted.imag)
    blocks[..., 1, 1] = 0.5 * (twisted.real - plain.real)
    return blocks


def jacobian_blocks(
    density: Density, batch: CellBatch, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """dc/dp blocks of a weighed batch, eqs. (6) and (7) (Section 2.3) with phi.

    off (K, L, 2, 2): -int_{dV_ij} (q - c_i)(q - p_j)^T phi / (m_i |p_i - p_j|) for the
    edge on line l shared with robot j = labels[k, l], zero elsewhere; diagonal (K, 2, 2):
    the sum over j of the same integrals with p_i in place of p_j, plus sign. Empty cells
    get zero blocks (as covswarm.tvd.coverage.jacobian_blocks).

    On an edge, int (q - c)(q - p_j)^T phi ds = X + Y (p_i - p_j)^T with X the same integral
    about p_i and Y = int (q - c) phi ds. The floor's part is the Lemma's bracket (as in
    covswarm.tvd.coverage.jacobian_blocks): from the edge's start v, u = v - c, w = v - p_i
    and d the edge, X = |d| [u (w + d/2)^T + d (w/2 + d/3)^T], Y = |d| (u + d/2). Each
    bump's, with q = foot + t beta along the edge, P = foot - c and Q = foot - p_i:
    X = |beta| [P (E0 Q + E1 beta)^T + beta (E1 Q + E2 beta)^T], Y = |beta| (E0 P + E1 beta).
    """
    plain, twisted, column, gap = _jacobian_sums(density, batch, points)
    off = np.zeros((*batch.labels.shape, 2, 2))
    off[:, : gap.shape[1]] = -_outer_blocks(plain + column * gap, twisted + column * gap.conj())
    return off, _outer_blocks(plain.sum(axis=1), twisted.sum(axis=1))


def jacobian_times(
    density: Density, batch: CellBatch, points: np.ndarray, own: np.ndarray, others: np.ndarray
) -> np.ndarray:
    """(J w)_i = sum_j dc_i/dp_j w_j for a weighed batch, (K,) complex: ``jacobian_blocks``
    applied to own (K,) w_i and others (K, L) w_j (read on shared edges only) without
    forming the blocks. A block given as the complex sums plain = sum a b and twisted =
    sum a conj(b) (``_outer_blocks``) maps w to sum a (b . w) = (plain conj(w) + twisted w) / 2.
    """
    plain, twisted, column, gap = _jacobian_sums(density, batch, points)
    w = np.where(batch.shared[:, : gap.shape[1]], others[:, : gap.shape[1]], 0.0)
    diagonal = plain.sum(axis=1) * own.conj() + twisted.sum(axis=1) * own
    off = (plain + column * gap) * w.conj() + (twisted + column * gap.conj()) * w
    return 0.5 * (diagonal - off.sum(axis=1))


def _jacobian_sums(
    density: Density, batch: CellBatch, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The complex sums of ``jacobian_blocks``' edge integrals, (K, L') each, L' the lines
    used: plain and twisted (``_outer_blocks``) of X / (m_i |p_i - p_j|), column =
    Y / (m_i |p_i - p_j|), all three zero off shared edges, and gap = p_i - p_j."""
    integrals = _integrals(density, batch)
    # The lines of the integrals (a reused batch's may be more than this one needs: padding).
    lines = _trim(batch) if integrals is None else integrals.edges.h.shape[1]
    where = as_complex(points)
    me = where[batch.owners][:, None]
    gap = me - np.take(where, batch.labels[:, :lines], mode="wrap")  # polygon lines: masked
    scale = np.divide(
        1.0, np.abs(gap) * batch.mass[:, None], out=np.zeros(gap.shape),
        where=batch.shared[:, :lines],
    )  # fmt: skip
    start = batch.start[:, :lines]
    d = batch.end[:, :lines] - start
    u = start - batch.centroid[:, None]
    w = start - me
    length = (density.floor * scale) * np.abs(d)
    first, second = w + 0.5 * d, 0.5 * w + d / 3.0
    plain = length * (u * first + d * second)
    twisted = length * (u * first.conj() + d * second.conj())
    column = length * (u + 0.5 * d)
    if integrals is not None:
        bumps, edges = integrals.bumps, integrals.edges
        foot, beta, speed = _edge_lines(bumps, edges)
        weight = (scale[..., None] * bumps.weights) * speed
        about_c = foot - batch.centroid[:, None, None]
        about_me = foot - me[..., None]
        near = weight * (edges.e0 * about_me + edges.e1 * beta)
        far = weight * (edges.e1 * about_me + edges.e2 * beta)
        plain = plain + (about_c * near + beta * far).sum(axis=2)
        twisted = twisted + (about_c * near.conj() + beta * far.conj()).sum(axis=2)
        column = column + (weight * (edges.e0 * about_c + edges.e1 * beta)).sum(axis=2)
    return plain, twisted, column, gap


def centroid_rates(
    density: Density, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
) -> np.ndarray:
    """dc_i/dt of Proposition 1 (Section 3, eq. (9)) for a weighed batch, (K,) complex: both terms.

    (1/m_i) int_{V_i} (q - c_i) dphi/dt + (1/m_i) int_{dS_i} (q - c_i) phi nu, with nu the
    outward normal speed of S, linear along each edge of S. An empty cell gets the velocity
    of its nearest point of S.
    """
    floor_rates = uniform_boundary_rates(batch, points, domain)
    integrals = _integrals(density, batch)
    if integrals is None:
        return np.where(batch.empty, floor_rates, density.floor * floor_rates)
    bumps, edges = integrals.bumps, integrals.edges
    # The dphi/dt term: with x = q - mu = L y, dphi_b/dt = g [w_dot + w (a . y + y^T M y)]
    # and q - c = L y + (mu - c), its integral is det L [L (w_dot m1 + w (m2 a + m3 : M))
    # + (mu - c)(w_dot m0 + w (a . m1 + M : m2))].
    w, w_dot = bumps.weights, bumps.weight_rates
    along = w_dot * integrals.m1 + w * (integrals.m2_a + integrals.m3_m)
    a_m1 = (bumps.drift.conj() * integrals.m1).real
    across = w_dot * integrals.m0 + w * (a_m1 + integrals.m_m2)
    offset = bumps.centers - batch.centroid[:, None]
    inner = (bumps.scale * (bumps.unwhiten(along) + offset * across)).sum(axis=1)
    lines = edges.h.shape[1]
    boundary = batch.boundary[:, :lines]
    if boundary.any():  # the boundary term: nu linear along the edge, nu = nu_f + t slope
        foot, beta, speed = _edge_lines(bumps, edges)
        edge = np.where(boundary, ~batch.labels[:, :lines], 0)[..., None]
        gradient = domain.speed_gradient[edge].conj()
        nu = domain.speed_offset[edge] + (gradient * foot).real
        slope = (gradient * beta).real
        about_c = foot - batch.centroid[:, None, None]
        weight = np.where(boundary[..., None], w * speed, 0.0)
        integral = about_c * (nu * edges.e0 + slope * edges.e1) + beta * (
            nu * edges.e1 + slope * edges.e2
        )
        inner = inner + (weight * integral).sum(axis=(1, 2))
    empty = batch.empty
    rates = density.floor * floor_rates + inner / np.where(empty, 1.0, batch.mass)
    return np.where(empty, floor_rates, rates)
