"""The console shows a map's picture and the route of a goto another client sent (issue 20,
item 7), end to end in Debian's Chromium: ``covswarm run`` on scenarios/lab-route.toml (3
robots; the lab's occupancy map, scenarios/lab.yaml), ``covswarm console`` and ``covswarm
steer --goto``, real processes over Zenoh on loopback, no mocks.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from browser_pages import BLUE_OVER_GREEN, COLOUR, console, open_page
from live_runs import running_swarm

from covswarm.deploy.plan import covswarm_argv

pytestmark = pytest.mark.e2e

LAB = Path(__file__).parents[1] / "scenarios" / "lab-route.toml"
TEAM = 3
# World points of scripts/make_lab_map.py's lab: on the bench at x in [-4.6, -2.2], y in
# [2.0, 2.6], and the same point mirrored to y < 0, free floor (a picture drawn upside down
# would swap them); off the 1 m grid lines and the pieces' labels.
BENCH, FLOOR = (-2.7, 2.3), (-2.7, -2.3)
GOAL = (2.6, -0.6)  # in the right room: the route shrinks S through the door


@pytest.fixture(scope="module")
def lab_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """(endpoint, swarm) of a running lab-route mission; everything of it killed at the end."""
    folder = tmp_path_factory.mktemp("console-map")
    with running_swarm(
        folder, "--agents", str(TEAM), "--scenario", str(LAB), "--duration", "300"
    ) as found:
        yield found


def test_the_map_picture_and_another_clients_route_are_drawn(lab_run, browser) -> None:  # noqa: F811
    endpoint, swarm = lab_run
    with console(endpoint, swarm) as url:
        page = open_page(browser, url)
        # The picture arrives (asked once by the console) and is drawn under the pieces.
        page.wait_for_function("document.body.dataset.mapDrawn !== undefined", timeout=15000)
        drawn = page.evaluate("window.covswarm.world().map")
        assert drawn == {"origin": [-5.0, -3.0], "resolution": 0.05, "width": 200,
                         "height": 120}  # fmt: skip
        wall = page.evaluate(COLOUR, list(BENCH))
        floor = page.evaluate(COLOUR, list(FLOOR))
        # Black picture under the translucent grey piece (the piece alone: #9aa5ad, ~160).
        assert max(wall) < 120, wall
        assert min(floor) > 230, floor  # the picture's white (the bare canvas reads 0)

        # A goto from another client: `covswarm steer --goto`, not this page.
        steer = subprocess.run(
            [*covswarm_argv(), "steer", "--connect", endpoint, "--swarm", swarm,
             "--goto", f"{GOAL[0]},{GOAL[1]}", "--timeout", "20"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert steer.returncode == 0, steer.stdout + steer.stderr
        line = next(row for row in steer.stdout.splitlines() if row.startswith("route: "))
        stops = np.array(
            [[float(x), float(y)] for x, y in re.findall(r"\(([-\d.]+), ([-\d.]+)\)", line)]
        )
        assert len(stops) >= 3 and np.allclose(stops[-1], GOAL, atol=1e-3), line
        page.wait_for_function(
            f"document.body.dataset.routePoints === '{len(stops)}'", timeout=5000
        )
        route = page.evaluate("window.covswarm.state().route")
        assert route["wall"] is None  # told by the coordinator's Status, not a reply here
        assert np.allclose(np.array(route["waypoints"])[:, :2], stops, atol=2e-3)
        assert len(route["shape"]) >= 3  # S's outline drawn at each stop
        mid = (stops[0] + stops[1]) / 2
        # The route's line (#8e44ad) crosses there: steelblue (S, 50) and the stops' dotted
        # outlines (63) are less blue.
        purple = page.evaluate(BLUE_OVER_GREEN, mid.tolist())
        assert purple > 80, purple
        page.close()
