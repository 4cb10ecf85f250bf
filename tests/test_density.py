"""covswarm.tvd.density: phi(q, t) as Gaussian bumps on a floor, and coverage with it.

Oracles: scipy dblquad over the shapely reference cells (masses, centroids), the closed
form of a Gaussian over a square (narrow bumps), central finite differences in positions
and in time while the domain moves and the bumps move (dc/dp, dc/dt, dphi/dt), and the
full team's TVD-D1 (local step). Relative error <= 1e-5 unless stated.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from reference import (
    KINDS,
    fd_jacobian,
    fd_valid,
    motion,
    random_convex_polygon,
    random_cov,
    random_robots,
    reference_cells,
    scale_of,
    two_hop,
)
from scipy import integrate
from scipy.special import erf

from covswarm.mission.motion import DensityPath
from covswarm.mission.scenario_files import load_scenario, scenario_from_dict
from covswarm.tvd import control, coverage
from covswarm.tvd.density import Density

TOL = 1e-5


def random_density(rng: np.random.Generator, polygon: np.ndarray) -> Density:
    """Two moving bumps (one a shallow hole) near S, sized 0.15 and 0.3 of its diameter."""
    diam = scale_of(polygon)
    return Density(
        floor=0.5,
        means=polygon.mean(axis=0) + rng.normal(size=(2, 2)) * 0.2 * diam,
        covariances=[random_cov(rng, 0.15 * diam), random_cov(rng, 0.3 * diam)],
        weights=[3.0, -0.3],
        mean_rates=rng.normal(size=(2, 2)) * diam,
        covariance_rates=[random_cov(rng, 0.1 * diam), -random_cov(rng, 0.05 * diam)],
        weight_rates=[1.0, 0.1],
    )


def fan_integral(cell, f) -> float:
    """int over a shapely polygon of f(q) (q: (2,)) by dblquad on a fan of triangles."""
    xy = np.asarray(cell.exterior.coords)[:-1]
    o, total = xy[0], 0.0
    for a, b in zip(xy[1:-1], xy[2:], strict=True):
        jac = abs((a - o)[0] * (b - o)[1] - (a - o)[1] * (b - o)[0])
        value = integrate.dblquad(
            lambda v, u, a=a, b=b: f(o + u * (a - o) + v * (b - o)),
            0,
            1,
            0,
            lambda u: 1 - u,
            epsrel=1e-12,
        )[0]
        total += jac * value
    return total


def test_mass_centroid_against_dblquad() -> None:
    rng = np.random.default_rng(11)
    polygon = random_convex_polygon(rng, k=5, scale=2.0, offset=1.0)
    positions = random_robots(rng, polygon, 4)
    density = random_density(rng, polygon)
    mass, centroid = coverage.mass_centroid(positions, polygon, density)
    for i, cell in enumerate(reference_cells(positions, polygon)):
        m = fan_integral(cell, lambda q: density.phi(q))
        c = [fan_integral(cell, lambda q, k=k: q[k] * density.phi(q)) / m for k in (0, 1)]
        assert abs(mass[i] - m) <= TOL * m
        assert np.linalg.norm(centroid[i] - c) <= TOL * np.sqrt(cell.area)


@pytest.mark.parametrize("ratio", [1e-4, 1e-2, 2.0, 24.0, 96.0, 1e3, 1e4])
def test_narrow_and_wide_bump_accuracy(ratio: float) -> None:
    """One square cell of side 1, a round bump of deviation 1 / ratio off its centre.

    From a bump 1e4 times wider than the cell to one 1e4 times narrower, against the
    closed form with erf (the first quadrature lost accuracy beyond 24: 4e-5 at 96).
    """
    sigma, mu, w, floor = 1.0 / ratio, np.array([0.37, 0.61]), 10.0, 0.1
    polygon = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    density = Density(floor, [mu], [np.eye(2) * sigma**2], [w])
    mass, centroid = coverage.mass_centroid(np.array([[0.5, 0.5]]), polygon, density)
    lo, hi = -mu / (np.sqrt(2) * sigma), (1.0 - mu) / (np.sqrt(2) * sigma)
    zeroth = sigma * np.sqrt(np.pi / 2) * (erf(hi) - erf(lo))  # per axis
    # exp(-lo^2) - exp(-hi^2) without cancellation (wide bumps) or overflow (narrow ones).
    near, far = np.minimum(lo**2, hi**2), np.maximum(lo**2, hi**2)
    difference = np.sign(hi**2 - lo**2) * -np.exp(-near) * np.expm1(near - far)
    first = mu * zeroth + sigma**2 * difference
    m = floor + w * zeroth[0] * zeroth[1]
    c = (0.5 * floor + w * first * zeroth[::-1]) / m
    assert abs(mass[0] - m) <= 1e-9 * m
    assert np.linalg.norm(centroid[0] - c) <= 1e-9


@pytest.mark.parametrize("seed", [5, 6])
def test_derivatives_against_finite_differences(seed: int) -> None:
    """dc/dp in positions; dc/dt while S translates, scales, rotates... and phi moves."""
    rng = np.random.default_rng(seed)
    while True:
        polygon = random_convex_polygon(rng, scale=1.0, offset=2.0)
        positions = random_robots(rng, polygon, int(rng.integers(3, 7)))
        if fd_valid(positions, polygon):
            break
    density = random_density(rng, polygon)
    h = 1e-6 * scale_of(polygon)
    jacobian = coverage.centroid_jacobian(positions, polygon, density)
    fd = fd_jacobian(lambda p: coverage.mass_centroid(p, polygon, density)[1], positions, h)
    assert np.linalg.norm(jacobian - fd) <= TOL * max(np.linalg.norm(fd), 1.0)
    for kind in KINDS:
        moving, velocity = motion(kind, polygon, rng)
        rate = coverage.centroid_rate(positions, polygon, velocity, density)
        ahead, behind = (
            coverage.mass_centroid(positions, moving(t), density.at(t))[1] for t in (1e-6, -1e-6)
        )
        fd_rate = (ahead - behind) / 2e-6
        scale = max(np.linalg.norm(fd_rate), np.abs(velocity).max())
        assert np.linalg.norm(rate - fd_rate) <= TOL * scale, kind


def test_density_rate_is_time_derivative() -> None:
    rng = np.random.default_rng(2)
    polygon = random_convex_polygon(rng, scale=1.0, offset=0.0)
    density = random_density(rng, polygon)
    q = polygon.mean(axis=0) + rng.normal(size=(50, 2)) * 0.5
    fd = (density.at(1e-6).phi(q) - density.at(-1e-6).phi(q)) / 2e-6
    assert np.allclose(density.rate(q), fd, rtol=1e-6, atol=1e-8)
    # A turning bump's path: its snapshot's rates are the path's derivatives.
    path = DensityPath(density, np.array([0.4, -1.3]))
    later, before, now = path(0.3 + 1e-6), path(0.3 - 1e-6), path(0.3)
    assert np.allclose((later.covariances - before.covariances) / 2e-6, now.covariance_rates)
    assert np.allclose((later.phi(q) - before.phi(q)) / 2e-6, now.rate(q), rtol=1e-6, atol=1e-8)


def test_floor_only_density_is_uniform() -> None:
    rng = np.random.default_rng(8)
    polygon = random_convex_polygon(rng)
    positions = random_robots(rng, polygon, 9, outside_fraction=0.2)
    velocity = motion("combo", polygon, rng)[1]
    flat = Density(floor=2.5, means=np.zeros((0, 2)), covariances=[], weights=[])
    mass, centroid = coverage.mass_centroid(positions, polygon, flat)
    mass0, centroid0 = coverage.mass_centroid(positions, polygon)
    scale = scale_of(polygon)
    assert np.allclose(mass, 2.5 * mass0, rtol=1e-12, atol=1e-12 * scale**2)
    assert np.allclose(centroid, centroid0, atol=1e-12 * scale)
    for function in (coverage.centroid_jacobian, coverage.aggregate_error):
        assert np.allclose(
            function(positions, polygon, flat), function(positions, polygon), atol=1e-10 * scale
        )
    for law in (control.tvd_d1, control.tvd_c):
        assert np.allclose(
            law(positions, polygon, velocity, 1.5, density=flat),
            law(positions, polygon, velocity, 1.5),
            atol=1e-10 * scale,
        )


@pytest.mark.parametrize("branch", ["solve", "fallback"])
def test_exact_tvd_c_with_density_takes_the_branch_its_rule_names(branch: str) -> None:
    """The exact TVD-C solves (I - dc/dp) pdot = r unless a speed would exceed
    max_amplification * max |r|; then it returns the guarded TVD-D1 rows and says so
    (``TeamStep.fallback``). The limit is set on either side of this layout's measured
    amplification, so each branch is taken for certain, and the flag must name it."""
    rng = np.random.default_rng(4)
    polygon = random_convex_polygon(rng, scale=1.0)
    positions = random_robots(rng, polygon, 8)
    density = random_density(rng, polygon)
    velocity = motion("rotate", polygon, rng)[1]
    jacobian = coverage.centroid_jacobian(positions, polygon, density)
    _, centroid = coverage.mass_centroid(positions, polygon, density)
    reference = 1.5 * (centroid - positions) + coverage.centroid_rate(
        positions, polygon, velocity, density
    )
    expected = np.linalg.solve(np.eye(len(jacobian)) - jacobian, reference.ravel()).reshape(-1, 2)
    largest = np.linalg.norm(reference, axis=1).max()
    amplification = np.linalg.norm(expected, axis=1).max() / largest
    limit = 2.0 * amplification if branch == "solve" else 0.5 * amplification
    args = (positions, polygon, velocity, 1.5)
    step = control.team_step("c", *args, density=density, max_amplification=limit, damping=0.0)
    assert step.fallback == (branch == "fallback")
    if branch == "solve":
        np.testing.assert_allclose(step.velocity, expected, rtol=0, atol=1e-9 * largest)
    else:
        d1 = control.team_step("d1", *args, density=density, max_amplification=limit)
        np.testing.assert_allclose(step.velocity, d1.velocity, rtol=0, atol=1e-12 * largest)
    # With the shipped limit the flag follows the same rule (this layout is far from the edge).
    assert abs(amplification / control.MAX_AMPLIFICATION - 1.0) > 0.05
    shipped = control.team_step("c", *args, density=density, damping=0.0)
    assert shipped.fallback == (amplification > control.MAX_AMPLIFICATION)


def test_jacobian_times_applies_the_blocks() -> None:
    """The robot's step multiplies dc/dp without forming its blocks: the same products as
    the blocks (tested against finite differences above) on random vectors, for a batch and
    for its first row (whose integrals are the batch's, reused)."""
    rng = np.random.default_rng(8)
    for _ in range(5):
        polygon = random_convex_polygon(rng, scale=2.0)
        positions = random_robots(rng, polygon, 9, outside_fraction=0.1)
        density = random_density(rng, polygon).at(rng.uniform(0.0, 0.1))
        domain = coverage.make_domain(polygon, np.zeros_like(polygon))
        owners = np.arange(len(positions))
        everyone = owners[None]
        batch = density.weigh(coverage.build_cells(positions, owners, everyone, domain))
        for rows in (slice(None), slice(0, 1)):
            cells = control._rows(batch, rows)
            own = rng.normal(size=len(cells.owners)) + 1j * rng.normal(size=len(cells.owners))
            others = rng.normal(size=cells.labels.shape) + 1j * rng.normal(size=cells.labels.shape)
            off, diagonal = density.jacobian_blocks(cells, positions)
            expected = np.einsum("kab,kb->ka", diagonal, coverage.as_vectors(own)) + np.einsum(
                "klab,klb->ka",
                off,
                coverage.as_vectors(np.where(cells.shared, others, 0.0)),
            )
            product = density.jacobian_times(cells, positions, own, others)
            scale = np.abs(expected).max()
            assert np.abs(coverage.as_vectors(product) - expected).max() <= 1e-12 * scale


@pytest.mark.parametrize("feedforward", [True, False])
def test_local_velocity_equals_team_row(feedforward: bool) -> None:
    rng = np.random.default_rng(21)
    polygon = random_convex_polygon(rng, scale=3.0)
    positions = random_robots(rng, polygon, 14, outside_fraction=0.1)
    density = random_density(rng, polygon)
    velocity = motion("combo", polygon, rng)[1]
    team = control.tvd_d1(positions, polygon, velocity, 2.0, feedforward, density=density)
    adjacency = coverage.neighbors(positions, polygon)
    mass = coverage.mass_centroid(positions, polygon, density)[0]
    # An empty cell's local view is exact only with its planar Voronoi neighbours (as in
    # tests/test_control.py); the quadrature is per cell, so the rows match to rounding.
    for i in np.flatnonzero(mass > 0):
        view = {j: positions[j] for j in two_hop(adjacency, i)}
        local = control.local_velocity(i, view, polygon, velocity, 2.0, feedforward, density)
        assert np.allclose(local, team[i], rtol=1e-9, atol=1e-12 * scale_of(polygon))


def test_to_dict_round_trip() -> None:
    density = random_density(np.random.default_rng(1), np.eye(3)[:, :2]).at(2.5)
    again = Density.from_dict(density.to_dict())
    assert again.to_dict() == density.to_dict()
    assert again.time == 2.5


GOOD = {"floor": 1.0, "bumps": [{"mean": [0, 0], "cov": [[1, 0], [0, 1]], "weight": 2.0}]}


def bad(**changes) -> dict:
    bump = {**GOOD["bumps"][0], **changes.pop("bump", {})}
    return {**GOOD, "bumps": [bump], **changes}


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (bad(floor=0.0), "phi can reach"),
        (bad(bump={"weight": -1.0}), "phi can reach"),
        (bad(floor=float("nan")), "finite"),
        (bad(bump={"cov": [[1, 0.5], [0, 1]]}), "not symmetric"),
        (bad(bump={"cov": [[1, 2], [2, 1]]}), "not positive definite"),
        (bad(bump={"cov": [[-1, 0], [0, -1]]}), "not positive definite"),
        (bad(bump={"mean": [0, float("inf")]}), "NaN or inf"),
        (bad(bump={"mean": [0, 0, 0]}), r"bump 0 mean must be \[x, y\], got \[0, 0, 0\]"),
        (bad(bump={"mean": [0, 0.5, 1, 1]}), r"bump 0 mean must be \[x, y\]"),
        (bad(bump={"mean": {"x": 0, "y": 0}}), r"bump 0 mean must be \[x, y\]"),
        (bad(bump={"mean_rate": [0.1, 0, 0]}), r"bump 0 mean_rate must be \[x, y\]"),
        (bad(bump={"cov": [1, 0, 0, 1]}), r"bump 0 cov must be \[\[a, b\], \[c, d\]\]"),
        (bad(bump={"cov": [[[1, 0], [0, 1]]]}), r"bump 0 cov must be \[\[a, b\]"),
        (bad(bump={"cov": [[1, 0], [0]]}), r"bump 0 cov must be \[\[a, b\]"),
        (bad(bump={"weight": "8"}), "bump 0 weight must be a number, got '8'"),
        (bad(bump={"weight": True}), "bump 0 weight must be a number, got True"),
        (bad(bump={"weight_rate": [1]}), "bump 0 weight_rate must be a number"),
        (bad(bump={"cov": [[1e300, 0], [0, 1e300]]}), "too large or too small"),
        (bad(bump={"cov": [[1e-300, 0], [0, 1e-300]]}), "too large or too small"),
        (bad(bump={"color": 1}), r"bump 0: unknown keys \['color'\]; the keys are mean,"),
        (bad(sigma=1), r"unknown keys \['sigma'\]; the keys are floor, bumps, t"),
        ({**GOOD, "bumps": GOOD["bumps"] * 17}, "at most 16"),
        ({"bumps": []}, "needs 'floor'"),
        ([1.0], "map"),
    ],
)
def test_bad_densities_raise(data, reason: str) -> None:
    """Refused with the key and the form expected: never reshaped or converted into
    something else (a flat covariance, a string weight), nor a numpy message or warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning would fail the test
        with pytest.raises(ValueError, match=reason):
            Density.from_dict(data)


def test_the_constructor_takes_arrays_of_their_shape_only() -> None:
    """Never reshaped: means given as (2, B) (x's row, y's row) would be read as scrambled
    points, a flat covariance as a matrix."""
    xs, ys = np.array([0.0, 1.0, 2.0]), np.array([5.0, 6.0, 7.0])
    covariances, weights = np.tile(0.1 * np.eye(2), (3, 1, 1)), np.ones(3)
    with pytest.raises(
        ValueError, match=r"means must be numbers of shape \(B, 2\), shape \(2, 3\)"
    ):
        Density(0.1, np.vstack([xs, ys]), covariances, weights)
    with pytest.raises(ValueError, match=r"covariances must be numbers of shape \(1, 2, 2\)"):
        Density(0.1, [[0.0, 0.0]], [0.1, 0.0, 0.0, 0.1], [1.0])
    with pytest.raises(ValueError, match=r"weights must be numbers of shape \(3,\), shape \(\)"):
        Density(0.1, np.column_stack([xs, ys]), covariances, 1.0)
    good = Density(0.1, np.column_stack([xs, ys]), covariances, weights)
    np.testing.assert_array_equal(good.means[:, 0], xs)
    assert Density(0.1, [], [], []).means.shape == (0, 2)  # no bump: uniform


def test_advancing_into_an_invalid_density_raises() -> None:
    density = Density.from_dict(bad(bump={"cov_rate": [[-1, 0], [0, 0]]}))
    density.at(0.5)
    with pytest.raises(ValueError, match="positive definite"):
        density.at(1.5)


def test_the_unvalidated_advance_equals_the_validated_snapshot() -> None:
    """``at`` skips the full validation when its cheap checks pass: same values bit for
    bit as the constructor's, and the constructor's refusals otherwise."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        density = random_density(rng, random_convex_polygon(rng))
        t = rng.uniform(-0.05, 0.05)
        fast = density.at(t)
        full = Density(
            density.floor, density.means + t * density.mean_rates,
            density.covariances + t * density.covariance_rates,
            density.weights + t * density.weight_rates,
            density.mean_rates, density.covariance_rates, density.weight_rates, t,
        )  # fmt: skip
        for name in ("means", "covariances", "weights", "mean_rates", "covariance_rates"):
            assert np.array_equal(getattr(fast, name), getattr(full, name))
        assert (fast.time, fast.floor) == (full.time, full.floor)
        assert np.array_equal(fast.covariances, fast.covariances.transpose(0, 2, 1))
    fading = Density.from_dict(bad(bump={"weight": -0.5, "weight_rate": -1.0}))
    with pytest.raises(ValueError, match="phi can reach"):
        fading.at(1.0)
    exploding = Density.from_dict(bad(bump={"mean_rate": [1e308, 0.0]}))
    with np.errstate(over="ignore"), pytest.raises(ValueError, match="NaN or inf"):
        exploding.at(1e10)


def test_a_non_density_is_refused() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(TypeError, match="density"):
        coverage.mass_centroid(np.array([[0.5, 0.5]]), square, density=1.0)


def test_formation_scenario_density_and_toml_round_trip() -> None:
    import tomllib

    scenario = load_scenario("formation")
    again = scenario_from_dict(tomllib.loads(scenario.to_toml()))
    for t in (0.0, 13.0, scenario.duration):
        assert again.density(t).to_dict() == scenario.density(t).to_dict()
    assert load_scenario("circle").density(1.0) is None
    table = tomllib.loads(scenario.to_toml())
    table["density"]["bumps"][0]["cov"] = [[1.0, 0.0], [0.0, -1.0]]
    with pytest.raises(ValueError, match="positive definite"):
        scenario_from_dict(table)


def test_agent_brain_uses_the_broadcast_density() -> None:
    """A robot alone at the centre of S moves only because of the density's bump."""
    from covswarm import protocol
    from covswarm.agent.brain import AgentBrain
    from covswarm.agent.extrapolation import extrapolate_density

    wall = 1.7e9
    square = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
    pull = Density(floor=1.0, means=[[1.8, 1.0]], covariances=[np.eye(2) * 0.1], weights=[5.0])

    def decide(density: dict | None) -> tuple[bool, tuple[float, float]]:
        brain = AgentBrain(0)
        brain.on_pose(protocol.Pose(id=0, x=1.0, y=1.0, theta=0.0, stamp=wall, seq=0), now=0.0)
        message = protocol.Domain(
            seq=1, stamp=wall, t=0.0, state="running", vertices=square,
            velocities=[[0.0, 0.0]] * 4, kappa=1.0, density=density,
        )  # fmt: skip
        accepted = brain.on_domain(message, now=0.0)
        return accepted, brain.step(0.1, wall).velocity

    assert decide(None) == (True, pytest.approx((0.0, 0.0), abs=1e-12))
    accepted, velocity = decide(pull.to_dict())
    assert accepted and velocity[0] > 0.1 and abs(velocity[1]) < 1e-9
    broken = pull.to_dict()
    broken["bumps"][0]["cov"] = [[1.0, 0.0], [0.0, -1.0]]  # well-formed, not a covariance
    assert decide(broken)[0] is False

    # Between broadcasts: advanced linearly, then held still; an invalid advance holds.
    drifting = Density(1.0, [[1.8, 1.0]], [np.eye(2) * 0.1], [5.0], [[0.1, 0.0]], time=3.0)
    assert extrapolate_density(None, 0.2, 1.0) is None
    assert extrapolate_density(drifting, 0.5, 1.0).means[0] == pytest.approx([1.85, 1.0])
    held = extrapolate_density(drifting, 5.0, 1.0)
    assert held.means[0] == pytest.approx([1.9, 1.0]) and not held.mean_rates.any()
    fading = Density(1.0, [[1.8, 1.0]], [np.eye(2) * 0.1], [5.0], weight_rates=[-10.0])
    assert extrapolate_density(fading, 0.2, 1.0).weights[0] == pytest.approx(3.0)
    assert extrapolate_density(fading, 0.9, 1.0).weights[0] == 5.0  # w = -4 would be invalid


def test_phi_takes_points_only() -> None:
    density = Density.from_dict(GOOD)
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 2\), got \(3,\)"):
        density.phi(np.array([1.0, 1.0, 1.0]))
    assert density.phi([0.0, 0.0]) == pytest.approx(3.0)  # floor + the bump's weight
