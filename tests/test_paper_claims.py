"""The paper's claims and the figures of the results pages, checked with the in-process
simulator.

1. Feedforward (dc/dt, Proposition 1) lowers the steady-state e_a (mean over the second half
   of the mission) on every moving built-in scenario, under every control law: short runs of
   small teams, so the check is cheap; it must win by a clear margin, not by round-off.
2. The figures of docs/results.json (the tables of docs/results.md and docs/density.md and the
   README's results table are rendered from it by scripts/results.py): every command there is
   rerun in-process with the options ``covswarm sim``'s own parser gives it, and every figure
   must fall within its band; each command must be on a page, and each page's tables must be
   what the file renders. Refreshing the figures is ``python scripts/results.py``; this file
   holds no figure of its own. About 3 minutes of CPU, run two at a time.
3. Why the paper's exact TVD-C falls back: the conditioning of I - dc/dp that
   docs/results.md states, far from and near a CVT.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections.abc import Iterator, Mapping
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from script_modules import load_script

from covswarm.deploy.simulate import simulate
from covswarm.mission.report import steady_state_mean
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import BUILTINS
from covswarm.tvd import coverage
from covswarm.tvd.control import LAWS

# ------------------------------------------------------------ 1. feedforward lowers e_a

# Small and short: the team size, mission length and step of each built-in's quick run.
# The passage keeps its full 45 s (its domain moves from 5 s to 41 s).
QUICK = {
    "circle": {"agents": 12, "duration": 16.0, "dt": 0.05},
    "passage": {"agents": 6, "dt": 0.05},
    "formation": {"agents": 8, "duration": 16.0, "dt": 0.05},
    "pinwheel": {"agents": 10, "duration": 16.0, "dt": 0.05},
    # its full 60 s route through the aisles (with / without feedforward measured 0.47 x for
    # d1, 0.008 x for c, 0.010 x for da on 2026-11-25)
    "warehouse": {"agents": 6, "dt": 0.05},
}
MARGIN = 0.9  # with feedforward <= 0.9 x without: measured 0.01 to 0.6 x


def moves(name: str) -> bool:
    """True if the built-in's domain has a nonzero vertex velocity at some sampled time."""
    scenario = load_scenario(name)
    times = np.linspace(0.0, scenario.duration, 91)
    return any(np.abs(scenario.domain(t)[1]).max() > 0.0 for t in times)


def test_every_moving_builtin_has_a_quick_run() -> None:
    moving = {name for name in BUILTINS if moves(name)}
    assert moving and moving <= set(QUICK), f"add a quick run for {moving - set(QUICK)}"


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("name", sorted(QUICK))
def test_feedforward_lowers_steady_state_error(name: str, law: str) -> None:
    scenario = load_scenario(name)
    steady = {}
    for feedforward in (True, False):
        run = simulate(scenario, law=law, feedforward=feedforward, seed=1, **QUICK[name])
        steady[feedforward] = steady_state_mean(run.t, run.error)
    assert steady[True] <= MARGIN * steady[False], steady


# ------------------------------------------------------------ 2. reproduction figures

ROOT = Path(__file__).resolve().parents[1]
RESULTS = json.loads((ROOT / "docs" / "results.json").read_text(encoding="utf-8"))
results_script = load_script("results")

# The bands. Spread measured on 2026-11-25 across three OpenBLAS kernels on one machine
# (OPENBLAS_CORETYPE unset = SkylakeX, Haswell, Prescott; numpy 2.4.6, scipy 1.17.1): every
# run below 0.3 % (most identical to the last digit), except the ones that the paper's exact
# TVD-C drives (its solve falls back on ~99 % of the steps and the run is chaotic: 7 % and
# 11 %; tested by invariants below, not by figure) and the TVD-C damped toward 0 (2.6 %).
E_A_REL, E_A_ABS = 0.03, 5e-5  # each steady-state e_a: 3 % or 0.05 mm, whichever is larger
CHAOTIC_REL = 0.08  # three times the 2.6 % kernel spread of the TVD-C damped toward 0
CHAOTIC = {"circle-c-zero"}
EXACT_C = {"circle-c-exact", "circle-c-exact-noff"}  # invariants only
POINTS = 0.03  # each improvement: 3 percentage points
NEIGHBORS = 2.0  # each mean count of Table 1: 2 robots
RATIO = 0.1  # the d1 / da ratio of the formation, as the pages round it (one decimal)

RUNS = {name: run["options"] for name, run in results_script.all_runs().items()}
ERROR_RUNS = sorted(set(RUNS) - EXACT_C)


def figures_of(options: dict) -> dict:
    """One run's figures, as scripts/results.py computes them (what summary.json reports)."""
    return results_script.figures_of(options)


class Sims(Mapping):
    """Figures of the runs of docs/results.json by name, each distinct option set simulated
    once, in the order of ERROR_RUNS and then the rest, by a pool of spawned processes (this
    one may hold other tests' threads); a test waits only for the runs it reads. Each test's
    wait then stays within pytest's per-test timeout: one fixture that waited for all 32
    (~540 s on a quiet slow host) went over it on a loaded one."""

    def __init__(self, pool: ProcessPoolExecutor) -> None:
        self._futures: dict[str, Future] = {}
        for name in [*ERROR_RUNS, *sorted(set(RUNS) - set(ERROR_RUNS))]:
            key = json.dumps(RUNS[name], sort_keys=True)
            if key not in self._futures:
                self._futures[key] = pool.submit(figures_of, RUNS[name])

    def __getitem__(self, name: str) -> dict:
        return self._futures[json.dumps(RUNS[name], sort_keys=True)].result()

    def __iter__(self) -> Iterator[str]:
        return iter(RUNS)

    def __len__(self) -> int:
        return len(RUNS)


@pytest.fixture(scope="module")
def sims() -> Iterator[Sims]:
    """:class:`Sims`, two at a time when the end-to-end tests do not run beside them
    (pytest -n 0: tests/conftest.py)."""
    workers = 1 if os.environ.get("PYTEST_XDIST_WORKER") else 2
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        yield Sims(pool)
        pool.shutdown(cancel_futures=True)


def test_results_json_holds_every_command_of_the_script() -> None:
    assert set(RESULTS["runs"]) == set(RUNS), set(RESULTS["runs"]) ^ set(RUNS)
    for name, run in RESULTS["runs"].items():
        assert run["command"] in results_script.COMMANDS, name
    assert RESULTS["refresh"] == "python scripts/results.py" and RESULTS["date"]


def test_every_command_is_on_a_page_and_every_table_is_rendered_from_the_file() -> None:
    pages = results_script.pages()
    assert {p.name for p in pages} >= {"results.md", "density.md", "README.md"}
    text = "\n".join(p.read_text(encoding="utf-8") for p in pages)
    for command in results_script.COMMANDS:
        assert command in text, f"no page names {command!r}"
    for page in pages:
        written = page.read_text(encoding="utf-8")
        assert results_script.render(written, RESULTS) == written, (
            f"{page.name}'s tables differ from docs/results.json: "
            "python scripts/results.py --render"
        )


@pytest.mark.parametrize("name", ERROR_RUNS)
def test_steady_state_error_within_its_band(name: str, sims: Sims) -> None:
    expected = RESULTS["runs"][name]["e_a"]
    band = max((CHAOTIC_REL if name in CHAOTIC else E_A_REL) * expected, E_A_ABS)
    assert abs(sims[name]["e_a"] - expected) <= band, (name, sims[name]["e_a"], expected)


COMPARED = sorted(n for n in ERROR_RUNS if f"{n}-noff" in RUNS)


@pytest.mark.parametrize("name", COMPARED)
def test_feedforward_improvement_within_its_band(name: str, sims: Sims) -> None:
    def gain(figures: Mapping[str, dict]) -> float:
        return 1.0 - figures[name]["e_a"] / figures[f"{name}-noff"]["e_a"]

    assert abs(gain(sims) - gain(RESULTS["runs"])) <= POINTS, (name, gain(sims))


def test_guards_are_as_recorded(sims: Sims) -> None:
    """A guard count of 0 (no row rescaled, no fallback) is exactly 0; only the exact TVD-C
    falls back (its invariants below)."""
    for name in ERROR_RUNS:
        recorded = RESULTS["runs"][name]
        if recorded["guarded"] == 0 and recorded["fallback_rate"] == 0:
            assert sims[name]["guarded"] == 0 and sims[name]["fallback_rate"] == 0, name
    assert all(RESULTS["runs"][n]["fallback_rate"] == 0 for n in ERROR_RUNS)


def test_tvd_da_on_the_formation_is_as_many_times_better(sims: Sims) -> None:
    def ratio(figures: Mapping[str, dict]) -> float:
        return figures["formation"]["e_a"] / figures["formation-da"]["e_a"]

    assert abs(ratio(sims) - ratio(RESULTS["runs"])) <= RATIO + 1e-9


def test_without_feedforward_tvd_da_is_tvd_d1(sims: Sims) -> None:
    """The laws table has one "without dc/dt (d1 and da)" column: without dc/dt both laws
    are (I + dc/dp) kappa (c - p), so their runs are the same run."""
    for scenario in results_script.SCENARIOS:
        d1, da = f"laws/{scenario}-d1-noff", f"laws/{scenario}-da-noff"
        assert RESULTS["runs"][d1]["e_a"] == RESULTS["runs"][da]["e_a"], scenario
        assert sims[d1]["e_a"] == pytest.approx(sims[da]["e_a"], rel=1e-9), scenario


def test_exact_tvd_c_is_tvd_d1_in_disguise(sims: Sims) -> None:
    """The paper's exact TVD-C is tested by what is invariant about it, not by its figure:
    its solve falls back to TVD-D1 on almost every step, so it lands near TVD-D1 and clearly
    below no feedforward. Measured on 2026-11-25 across three OpenBLAS kernels (SkylakeX,
    Haswell, Prescott), with the workspace walls open and solid (six runs): fallback on
    97.2 to 99.4 % of the steps; e_a 0.965 to 1.071 times TVD-D1's and at most 0.80 times
    TVD-D1's without feedforward; without feedforward it is chaotic too (0.126 to 0.171 m,
    1.05 to 1.43 times TVD-D1's)."""
    exact, d1 = sims["circle-c-exact"], sims["circle-d1"]
    assert exact["fallback_rate"] >= 0.93, exact
    assert 0.9 <= exact["e_a"] / d1["e_a"] <= 1.12, (exact, d1)
    assert exact["e_a"] <= 0.88 * sims["circle-d1-noff"]["e_a"], (exact, sims["circle-d1-noff"])
    assert sims["circle-c-exact-noff"]["fallback_rate"] >= 0.93
    assert 1.0 <= sims["circle-c-exact-noff"]["e_a"] / sims["circle-d1-noff"]["e_a"] <= 1.6


def test_neighbor_counts_of_table_1_within_their_band(sims: Sims) -> None:
    expected = results_script.table_1(RESULTS["runs"])
    mean = results_script.table_1(sims)
    for k, value in expected.items():
        assert mean[k] == pytest.approx(value, abs=NEIGHBORS), mean
    assert max(mean, key=mean.get) == 6  # most robots have 6 neighbours, as in the paper


# ------------------------------------------------------------ 3. why the exact TVD-C falls back

SQUARE = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])  # the circle's S


def conditioning(positions: np.ndarray) -> tuple[float, float]:
    """(spectral radius of dc/dp, smallest singular value of I - dc/dp) in SQUARE."""
    jacobian = coverage.centroid_jacobian(positions, SQUARE)
    radius = float(np.abs(np.linalg.eigvals(jacobian)).max())
    identity = np.eye(len(jacobian))
    return radius, float(np.linalg.svd(identity - jacobian, compute_uv=False).min())


def test_far_from_a_cvt_the_spectral_radius_is_above_one() -> None:
    """docs/library.md: "Far from a CVT the spectral radius of dc/dp is above 1: 1.7 to 31,
    median 4.4" (20 robots at random in a square, 100 layouts), so I - dc/dp can be near
    singular and the Neumann series diverges."""
    radii = [conditioning(np.random.default_rng(s).uniform(-1, 1, (20, 2)))[0] for s in range(100)]
    assert 1.6 <= min(radii) and 25.0 <= max(radii) <= 35.0, (min(radii), max(radii))
    assert 4.0 <= float(np.median(radii)) <= 5.0


def test_near_a_cvt_of_100_robots_i_minus_j_is_near_singular() -> None:
    """docs/results.md: near a CVT of 100 robots in a still square (Lloyd's algorithm from random
    starts, 3 cm to 4 mm from the CVT) the spectral radius of dc/dp is 1.03 to 1.22 and the
    smallest singular value of I - dc/dp 6e-5 to 8e-3."""
    radii, smallest = [], []
    for seed in range(3):
        positions = np.random.default_rng(seed).uniform(-1, 1, (100, 2))
        for iteration in range(1, 101):
            positions = coverage.mass_centroid(positions, SQUARE)[1]
            if iteration % 20 == 0:
                radius, sigma = conditioning(positions)
                radii.append(radius)
                smallest.append(sigma)
    assert 1.0 < min(radii) and max(radii) < 1.25, radii
    assert max(smallest) < 1e-2 and min(smallest) < 1e-3, smallest
