"""scripts/error_shares.py: e_a of a run folder at its recorded instants, and the share of
it the robots farthest from their centroids carry (a straggler outside S shows)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from script_modules import load_script
from shapely.geometry import Point, Polygon

from covswarm.tvd.coverage import aggregate_error


def write_run(folder: Path, frames: list[tuple[float, np.ndarray]], polygon: np.ndarray) -> None:
    """trajectories.csv and domain.csv of robots at ``frames`` (t, positions (n, 2)), S
    translating by +0.1 m in x per second from ``polygon``, as a run writes them."""
    lines = ["t,id,x,y,theta"]
    domain = ["t,vertex,x,y"]
    for t, positions in frames:
        lines += [f"{t},{i},{x},{y},0.0" for i, (x, y) in enumerate(positions)]
        domain += [f"{t},{k},{x + 0.1 * t},{y}" for k, (x, y) in enumerate(polygon)]
    (folder / "trajectories.csv").write_text("\n".join(lines) + "\n")
    (folder / "domain.csv").write_text("\n".join(domain) + "\n")


def test_e_a_and_the_stragglers_share(tmp_path: Path) -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    # a CVT of S: a 3 x 4 grid of rectangles, each robot at its centre
    xs, ys = np.meshgrid([1 / 3, 1.0, 5 / 3], [0.25, 0.75, 1.25, 1.75])
    inside = np.stack([xs.ravel(), ys.ravel()], axis=1) + np.random.default_rng(4).normal(
        0.0, 0.01, (12, 2)
    )
    straggler = np.array([[-0.8, 1.0]])  # outside S, far from anything it could own
    early = np.vstack([inside, [[1.0, 1.0]]])
    late = np.vstack([inside + [0.1, 0.0], straggler])
    write_run(tmp_path, [(0.0, early), (1.0, late)], square)
    rows = load_script("error_shares").shares(tmp_path, [0.0, 1.0], top=1)
    assert [row["t"] for row in rows] == [0.0, 1.0]
    assert rows[0]["e_a"] == pytest.approx(aggregate_error(early, square), rel=1e-12)
    moved = square + [0.1, 0.0]
    assert rows[1]["e_a"] == pytest.approx(aggregate_error(late, moved), rel=1e-12)
    expected_outside = sum(not Polygon(moved).covers(Point(p)) for p in late)
    assert rows[1]["outside"] == expected_outside == 1
    assert rows[0]["outside"] == 0
    # the straggler is 0.9 m from its nearest point of S: nearly all of e_a^2
    assert rows[1]["top_share"] > 0.9
    assert rows[1]["e_a_rest"] ** 2 == pytest.approx(
        rows[1]["e_a"] ** 2 * (1 - rows[1]["top_share"]), rel=1e-9
    )


def test_a_robot_not_yet_recorded_is_left_out(tmp_path: Path) -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    lines = "t,id,x,y,theta\n0.0,0,0.25,0.5,0.0\n1.0,0,0.25,0.5,0.0\n1.0,1,0.75,0.5,0.0\n"
    (tmp_path / "trajectories.csv").write_text(lines)
    write_domain = ["t,vertex,x,y"] + [f"0.0,{k},{x},{y}" for k, (x, y) in enumerate(square)]
    (tmp_path / "domain.csv").write_text("\n".join(write_domain) + "\n")
    first, last = load_script("error_shares").shares(tmp_path, [0.0, 1.0], top=1)
    assert first["e_a"] == pytest.approx(aggregate_error(np.array([[0.25, 0.5]]), square))
    assert last["e_a"] == pytest.approx(0.0, abs=1e-12)  # two robots at their centroids


def test_interpolated_between_records_as_at_the_time_itself(tmp_path: Path) -> None:
    """--interpolate: robots recorded at 0 and 1 s and S at 0 and 1 s, read at 0.3 s, give
    the e_a of the positions and S linear between them (the robots' straight moves and S's
    translation are linear, so that is the e_a at 0.3 s); the latest pose and the nearest S
    give another."""
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    rng = np.random.default_rng(7)
    start = rng.uniform(0.2, 1.8, (9, 2))
    end = start + rng.normal(0.0, 0.1, (9, 2))
    write_run(tmp_path, [(0.0, start), (1.0, end)], square)
    script = load_script("error_shares")
    (row,) = script.shares(tmp_path, [], top=1, seconds=[0.3], interpolate=True)
    between = 0.7 * start + 0.3 * end
    assert row["t"] == 0.3
    assert row["e_a"] == pytest.approx(aggregate_error(between, square + [0.03, 0.0]), rel=1e-12)
    (latest,) = script.shares(tmp_path, [], top=1, seconds=[0.3])
    assert latest["e_a"] == pytest.approx(aggregate_error(start, square), rel=1e-12)
    assert abs(latest["e_a"] - row["e_a"]) > 1e-3
