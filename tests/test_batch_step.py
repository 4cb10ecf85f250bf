"""``local_steps``: the brains due in one tick stepped as one batch.

Each view's result must equal its one-at-a-time ``local_step`` to 1e-9 (velocity, centroid,
mass, area; neighbours and the guard flag exactly), on random and near-CVT layouts, with and
without a density, for TVD-D1 and TVD-DA, from two-hop neighbourhoods as an agent holds
them, with views of different domains mixed in one call, an empty-cell robot and a robot
alone. Invalid input names the view.
"""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.deploy.bench import bench_density, make_layout, two_hop
from covswarm.tvd.control import LocalView, local_step, local_steps, team_step
from covswarm.tvd.coverage import (
    LOCAL_CANDIDATES,
    PRUNED_CELLS,
    CellBatch,
    JacobianTerms,
    apply_jacobian,
    build_cells,
    jacobian_terms,
    jacobian_times,
    local_cells,
    make_domain,
    neighbors,
)
from covswarm.tvd.safety import safe_unicycle_velocities, safe_velocity

TOL = 1e-9
KAPPA = 1.3


def moving(polygon: np.ndarray, spin: float = 0.05) -> np.ndarray:
    """Vertex velocities of ``polygon`` (k, 2) translating, turning and growing: (k, 2) m/s."""
    centre = polygon.mean(axis=0)
    offset = polygon - centre
    turn = spin * np.stack([-offset[:, 1], offset[:, 0]], axis=1)
    return np.array([0.05, -0.02]) + turn + 0.01 * offset


def team_views(n: int, kind: str, seed: int, density: bool, kappa: float = KAPPA) -> list:
    """Every robot's two-hop view of a bench layout (deploy.bench.make_layout)."""
    layout = make_layout(n, kind, seed, lloyd_iterations=30)
    adjacency = neighbors(layout.positions, layout.polygon)
    velocity = moving(layout.polygon)
    phi = bench_density(float(layout.polygon[:, 0].max())) if density else None
    return [
        LocalView(
            me,
            {j: layout.positions[j] for j in two_hop(adjacency, me)},
            layout.polygon,
            velocity,
            kappa,
            phi,
        )
        for me in range(n)
    ]


def one_by_one(views: list, law: str, feedforward: bool = True) -> list:
    return [
        local_step(
            v.me,
            v.positions,
            v.polygon,
            v.polygon_velocity,
            v.kappa,
            feedforward,
            v.density,
            law=law,
        )
        for v in views
    ]


def assert_same_steps(batch: list, single: list) -> None:
    assert len(batch) == len(single)
    for index, (got, want) in enumerate(zip(batch, single, strict=True)):
        where = f"view {index}"
        np.testing.assert_allclose(got.velocity, want.velocity, rtol=0, atol=TOL, err_msg=where)
        np.testing.assert_allclose(got.centroid, want.centroid, rtol=0, atol=TOL, err_msg=where)
        assert got.mass == pytest.approx(want.mass, rel=TOL, abs=TOL), where
        assert got.area == pytest.approx(want.area, rel=TOL, abs=TOL), where
        assert got.neighbors == want.neighbors, where
        assert got.guarded == want.guarded, where
        assert got.velocity.shape == (2,) and np.all(np.isfinite(got.velocity)), where


@pytest.mark.parametrize("kind", ["random", "cvt"])
@pytest.mark.parametrize("density", [False, True])
@pytest.mark.parametrize("law", ["d1", "da"])
def test_team_batch_equals_single_steps(kind: str, density: bool, law: str) -> None:
    views = team_views(36, kind, seed=3, density=density)
    single = one_by_one(views, law)
    batch = local_steps(views, law=law)
    assert_same_steps(batch, single)
    # And, from exact two-hop views, the full team's step (team_cells' own cells).
    first = views[0]
    positions = np.array([v.positions[v.me] for v in views])  # views[i].me == i
    team = team_step(
        law, positions, first.polygon, first.polygon_velocity, KAPPA, density=first.density
    )
    got = np.array([step.velocity for step in batch])
    np.testing.assert_allclose(got, team.velocity, rtol=0, atol=TOL)
    # The layouts exercise the law: moving robots, and (random) some rows guarded.
    assert max(np.linalg.norm(step.velocity) for step in single) > 0.01
    assert all(step.neighbors for step in single)


def test_without_feedforward_and_a_tight_guard() -> None:
    views = team_views(30, "random", seed=5, density=False)
    single = [
        local_step(v.me, v.positions, v.polygon, v.polygon_velocity, v.kappa, False, None, 1.2)
        for v in views
    ]
    assert any(step.guarded for step in single)  # the guard is exercised
    assert_same_steps(local_steps(views, feedforward=False, max_amplification=1.2), single)


def test_mixed_domains_densities_and_kappas_in_one_call() -> None:
    """Views of two teams (two domains, uniform and with a density), their order shuffled,
    each with its own gain, plus views that share a domain equal in value but not identity."""
    first = team_views(20, "cvt", seed=1, density=True)
    second = team_views(25, "random", seed=2, density=False, kappa=0.7)
    copies = [
        LocalView(v.me, v.positions, v.polygon.copy(), v.polygon_velocity.copy(), 2.0, v.density)
        for v in first[:5]
    ]
    views = first + second + copies
    order = np.random.default_rng(0).permutation(len(views))
    views = [views[i] for i in order]
    for law in ("d1", "da"):
        assert_same_steps(local_steps(views, law=law), one_by_one(views, law))


# Once, and repeated into a batch of at least PRUNED_CELLS views of one S, which finds the
# neighbours from the views' own cells instead (covswarm.tvd.control._view_cells).
@pytest.mark.parametrize("copies", [1, -(-PRUNED_CELLS // 5)])
def test_empty_cell_lone_robot_and_string_ids(copies: int) -> None:
    side = 3.0
    polygon = np.array([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]])
    velocity = moving(polygon)
    rng = np.random.default_rng(7)
    inside = {f"r{i}": rng.uniform(0.2, side - 0.2, size=2) for i in range(12)}
    outside = inside | {"far": np.array([-4.0, 1.5])}  # dominated: an empty cell
    duplicate = inside | {"r99": inside["r0"].copy()}  # coincident, higher id: empty
    views = [
        LocalView("far", outside, polygon, velocity, KAPPA),
        LocalView("r99", duplicate, polygon, velocity, KAPPA),
        LocalView("r3", inside, polygon, velocity, KAPPA),
        LocalView("lone", {"lone": np.array([1.0, 2.0])}, polygon, velocity, KAPPA),
        LocalView("out", {"out": np.array([5.0, 5.0])}, polygon, velocity, KAPPA),
        LocalView("far", outside, polygon, velocity, KAPPA, bench_density(side)),
    ]
    views = views[:5] * copies + views[5:]
    for law in ("d1", "da"):
        single = one_by_one(views, law)
        assert single[0].mass == 0.0 and single[1].mass == 0.0  # the cases are what they say
        assert single[3].neighbors == frozenset() and single[3].area == pytest.approx(side**2)
        assert_same_steps(local_steps(views, law=law), single)


def test_a_batch_where_nobody_has_neighbours() -> None:
    """PRUNED_CELLS views of one S, each of a robot alone (one of them outside S): no
    neighbours' cells to build."""
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    velocity = moving(polygon)
    spots = np.random.default_rng(4).uniform(-0.5, 2.5, size=(PRUNED_CELLS, 2))
    views = [LocalView(i, {i: spot}, polygon, velocity, KAPPA) for i, spot in enumerate(spots)]
    for law in ("d1", "da"):
        single = one_by_one(views, law)
        assert all(step.neighbors == frozenset() for step in single)
        assert_same_steps(local_steps(views, law=law), single)


def test_empty_batch() -> None:
    assert local_steps([]) == []


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ({"positions": {0: np.array([0.5, 0.5]), 1: np.array([np.nan, 1.0])}}, r"NaN.*\[1\]"),
        # 3-vectors: the batch's one conversion fails, the views are converted one by one
        ({"positions": {0: np.array([0.5, 0.5, 0.0]), 1: np.array([1.5, 1.5, 0.0])}}, "pairs"),
        # one robot's: named by its id
        ({"positions": {0: np.array([0.5, 0.5]), 1: [1.5, 1.5, 0.0]}}, r"robots \[1\]$"),
        ({"positions": {0: np.array([0.5, 0.5]), 1: "here"}}, r"robots \[1\]$"),
        ({"positions": [np.array([0.5, 0.5])]}, r"a mapping \{id: \(x, y\)\}, not a list"),
        ({"me": 5}, "positions must include"),
        ({"kappa": -1.0}, "kappa"),
        ({"polygon": np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])}, "zero area"),
    ],
)
def test_invalid_view_is_named(bad: dict, message: str) -> None:
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    good = {
        "me": 0,
        "positions": {0: np.array([0.5, 0.5]), 1: np.array([1.5, 1.5])},
        "polygon": polygon,
        "polygon_velocity": np.zeros((len(polygon), 2)),
        "kappa": 1.0,
    }
    fields = good | bad
    if len(fields["polygon_velocity"]) != len(fields["polygon"]):
        fields["polygon_velocity"] = np.zeros_like(fields["polygon"])
    views = [LocalView(**good), LocalView(**good), LocalView(**fields)]
    with pytest.raises(ValueError, match=rf"view 2 \(me={fields['me']!r}\).*{message}"):
        local_steps(views)


def test_bad_law_and_density_type() -> None:
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    view = LocalView(0, {0: np.array([0.5, 0.5])}, polygon, np.zeros((4, 2)), 1.0)
    with pytest.raises(ValueError, match="law"):
        local_steps([view], law="c")
    wrong = LocalView(0, view.positions, polygon, np.zeros((4, 2)), 1.0, density="phi")
    with pytest.raises(TypeError, match=r"view 1 \(me=0\)"):
        local_steps([view, wrong])


def test_local_cells_rebuild_a_cell_whose_neighbour_is_not_among_the_nearest() -> None:
    """A robot with 30 robots on its left and one far to its right, which bounds its cell:
    the first pass (the nearest LOCAL_CANDIDATES) misses that one, the radius test must
    catch it. Every cell equals ``build_cells``' with all candidates."""
    rng = np.random.default_rng(11)
    huddle = np.array([0.6, 2.0]) + rng.uniform(-0.3, 0.3, size=(15, 2))
    wall = np.stack([rng.uniform(0.05, 0.25, 15), rng.uniform(0.0, 4.0, 15)], axis=1)
    points = np.concatenate(([[1.0, 2.0], [5.0, 2.0]], huddle, wall))
    domain = make_domain(np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]]))
    n = len(points)
    assert n > LOCAL_CANDIDATES and n >= PRUNED_CELLS
    owners = np.arange(n)
    everyone = np.broadcast_to(owners, (n, n))
    pruned, full = (
        local_cells(points, owners, everyone, domain),
        build_cells(points, owners, everyone, domain),
    )
    assert 1 in full.labels[0][full.shared[0]]  # the far robot is robot 0's neighbour
    for k in range(n):
        assert set(pruned.labels[k][pruned.shared[k]]) == set(full.labels[k][full.shared[k]])
        np.testing.assert_allclose(pruned.vertices(k), full.vertices(k), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pruned.mass, full.mass, rtol=1e-12, atol=0)
    np.testing.assert_allclose(pruned.centroid, full.centroid, rtol=0, atol=1e-12)


def degenerate_layout(kind: str, rng: np.random.Generator) -> np.ndarray:
    """40 robots in or around the 6 x 4 m rectangle, (40, 2) m, as ``kind`` says."""
    if kind == "uniform":
        return rng.uniform([0.0, 0.0], [6.0, 4.0], size=(40, 2))
    if kind == "outside":  # some robots outside S, with empty or sliver cells
        return rng.uniform([-2.0, -1.0], [8.0, 5.0], size=(40, 2))
    if kind == "clustered":  # tight clusters: long, thin boundary cells
        centres = rng.uniform([0.5, 0.5], [5.5, 3.5], size=(4, 2))
        return centres[rng.integers(0, 4, 40)] + rng.normal(0.0, 0.05, size=(40, 2))
    if kind == "lattice":  # equidistant candidates, bisectors through shared vertices
        x, y = np.meshgrid(np.arange(8) * 0.75 + 0.2, np.arange(5) * 0.75 + 0.3)
        return np.stack([x.ravel(), y.ravel()], axis=1)
    if kind == "collinear":
        return np.stack([np.linspace(0.1, 5.9, 40), np.full(40, 2.0)], axis=1)
    layout = rng.uniform([0.0, 0.0], [6.0, 4.0], size=(40, 2))  # "coincident"
    layout[20:30] = layout[rng.integers(0, 20, 10)]
    return layout


@pytest.mark.parametrize(
    "kind", ["uniform", "outside", "clustered", "lattice", "collinear", "coincident"]
)
@pytest.mark.parametrize("seed", range(3))
def test_local_cells_equal_build_cells_with_every_candidate(kind: str, seed: int) -> None:
    """The pruned cells (the nearest first, rebuilt while a left-out robot may reach a
    vertex) are the cells of every candidate, to 1e-12, on random and degenerate layouts:
    the same edges, neighbours, empty cells and coincident robots' tie-breaks."""
    rng = np.random.default_rng(seed)
    points = degenerate_layout(kind, rng)
    domain = make_domain(np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]]))
    owners = np.arange(len(points))
    everyone = np.broadcast_to(owners, (len(points), len(points)))
    pruned = local_cells(points, owners, everyone, domain)
    full = build_cells(points, owners, everyone, domain)
    np.testing.assert_array_equal(pruned.empty, full.empty)
    for k in owners:
        assert set(pruned.labels[k][pruned.shared[k]]) == set(full.labels[k][full.shared[k]])
        np.testing.assert_allclose(pruned.vertices(k), full.vertices(k), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pruned.mass, full.mass, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pruned.centroid, full.centroid, rtol=0, atol=1e-12)


def test_jacobian_terms_of_some_rows_are_those_rows_terms() -> None:
    """TVD-DA's second product reads the first rows of the batch's terms: the same numbers
    as ``jacobian_times`` of those rows alone."""
    rng = np.random.default_rng(5)
    points = rng.uniform([0.0, 0.0], [6.0, 4.0], size=(40, 2))
    domain = make_domain(np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]]))
    owners = np.arange(len(points))
    cells = build_cells(points, owners, owners[None], domain)
    own = rng.normal(size=40) + 1j * rng.normal(size=40)
    others = np.where(cells.shared, own[np.maximum(cells.labels, 0)], 0.0)
    terms = jacobian_terms(cells, points)
    np.testing.assert_array_equal(
        apply_jacobian(terms, own, others), jacobian_times(cells, points, own, others)
    )
    head = JacobianTerms(*(t[:12] for t in terms))
    rows = CellBatch(**{f: getattr(cells, f)[:12] for f in CellBatch.__dataclass_fields__})
    np.testing.assert_array_equal(
        apply_jacobian(head, own[:12], others[:12]),
        jacobian_times(rows, points, own[:12], others[:12]),
    )


def random_filter_cases(count: int, seed: int) -> dict:
    """Robots in a 4 m square with 0 to 8 neighbours within 0.5 m (some closer than the safe
    distance: infeasible rows), their velocities, 0 to 3 box obstacles nearby, and a few
    robots or neighbours that are not finite."""
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0.3, 3.7, size=(count, 2))
    neighbors, theirs, obstacles = [], [], []
    for p in positions:
        k = int(rng.integers(0, 9))
        neighbors.append(p + rng.uniform(-0.4, 0.4, size=(k, 2)))
        theirs.append(rng.normal(0.0, 0.2, size=(k, 2)))
        corners = p + rng.uniform(-0.6, 0.4, size=(int(rng.integers(0, 4)), 2))
        obstacles.append([c + np.array([[0, 0], [0.2, 0], [0.2, 0.2], [0, 0.2]]) for c in corners])
    velocities = rng.normal(0.0, 0.2, size=(count, 2))
    nominal = rng.normal(0.0, 0.4, size=(count, 2))
    headings = rng.uniform(-np.pi, np.pi, size=count)
    positions[1], nominal[2], headings[3], velocities[4] = np.nan, np.inf, np.nan, np.nan
    neighbors[5] = np.concatenate([neighbors[5], [[np.nan, 1.0]]])
    theirs[5] = np.concatenate([theirs[5], [[0.0, 0.0]]])
    theirs[6][:1] = np.nan
    return {
        "positions": positions,
        "nominal": nominal,
        "headings": headings,
        "neighbors": neighbors,
        "velocities": velocities,
        "neighbor_velocities": theirs,
        "obstacles": obstacles,
        "gamma": rng.uniform(2.0, 10.0, size=count),
    }


@pytest.mark.parametrize("walled", [False, True, "some"])
@pytest.mark.parametrize("reciprocal", [False, True])
@pytest.mark.parametrize("per_row", [False, True])
def test_batch_unicycle_filter_equals_safe_velocity(
    walled: bool | str, reciprocal: bool, per_row: bool
) -> None:
    """walled: obstacles and one workspace for all; "some": a workspace for every other robot
    (brains of one process with and without a world). per_row: every other robot's pair rows
    with a gain of their own (covswarm.agent.brain.filter_all's second pass)."""
    count, safe = 300, 0.16
    case = random_filter_cases(count, seed=len(str(walled)) + 2 * int(reciprocal))
    rows = np.random.default_rng(9)
    gammas = [
        rows.uniform(0.5, 10.0, len(near)) if per_row and r % 2 else None
        for r, near in enumerate(case["neighbors"])
    ]
    shared = {"obstacle_distance": 0.1, "reach": 0.5} if walled else {}
    box = (0.0, 4.0, 0.0, 4.0)
    workspace = [box if r % 2 else None for r in range(count)] if walled == "some" else None
    workspace = box if walled is True else workspace
    velocity, active, relaxed = safe_unicycle_velocities(
        case["positions"],
        case["nominal"],
        case["headings"],
        case["neighbors"],
        safe,
        case["gamma"],
        velocities=case["velocities"] if reciprocal else None,
        neighbor_velocities=case["neighbor_velocities"] if reciprocal else None,
        obstacles=case["obstacles"] if walled else None,
        workspace=workspace,
        obstacle_gamma=0.5 * case["gamma"] if walled else None,
        neighbor_gammas=gammas if per_row else None,
        **shared,
    )
    for r in range(count):
        want = safe_velocity(
            case["positions"][r],
            case["nominal"][r],
            case["neighbors"][r],
            safe,
            float(case["gamma"][r]),
            heading=float(case["headings"][r]),
            velocity=case["velocities"][r] if reciprocal else None,
            neighbor_velocities=case["neighbor_velocities"][r] if reciprocal else None,
            obstacles=case["obstacles"][r] if walled else (),
            workspace=workspace[r] if isinstance(workspace, list) else workspace,
            obstacle_gamma=0.5 * float(case["gamma"][r]) if walled else None,
            neighbor_gammas=gammas[r],
            **shared,
        )
        np.testing.assert_allclose(velocity[r], want.velocity, rtol=0, atol=TOL, err_msg=f"{r}")
        assert (active[r], relaxed[r]) == (want.active, want.relaxed), r
    # The cases are what they claim: untouched, clipped and relaxed robots, zeros for bad input.
    assert np.sum(active == 0) > 20 and np.sum(active > 0) > 20 and np.sum(relaxed) > 5
    assert np.all(velocity[1:4] == 0.0)


def test_batch_unicycle_filter_edges() -> None:
    """No robots; robots without neighbours; bad arguments as safe_velocity's."""
    empty = safe_unicycle_velocities(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), [], 0.2)
    assert [len(x) for x in empty] == [0, 0, 0]
    nominal = np.array([[0.3, -0.1], [0.0, 0.2]])
    alone = safe_unicycle_velocities(np.ones((2, 2)), nominal, np.zeros(2), [[], []], 0.2)
    np.testing.assert_array_equal(alone[0], nominal)
    assert alone[1].tolist() == [0, 0] and not alone[2].any()
    with pytest.raises(ValueError, match="gamma > 0"):
        safe_unicycle_velocities(np.ones((1, 2)), nominal[:1], [0.0], [[]], 0.2, 0.0)
    with pytest.raises(ValueError, match="obstacle_distance"):
        safe_unicycle_velocities(
            np.ones((1, 2)), nominal[:1], [0.0], [[]], 0.2, workspace=(0, 2, 0, 2)
        )
    with pytest.raises(ValueError, match="workspace must be"):
        safe_unicycle_velocities(
            np.ones((2, 2)), nominal, [0.0, 0.0], [[], []], 0.2,
            workspace=[None, (0, 2, 2, 0)], obstacle_distance=0.1,
        )  # fmt: skip


@pytest.mark.parametrize("kappa", ["1", True, None, float("nan"), 0.0])
def test_a_gain_that_is_no_positive_number_is_named(kappa) -> None:
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    with pytest.raises(ValueError, match="kappa must be a positive finite gain"):
        local_step(0, {0: np.array([0.5, 0.5])}, polygon, np.zeros((4, 2)), kappa)
