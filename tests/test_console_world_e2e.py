"""The console shows the world (issue 20, item 7), in Debian's Chromium driven by Playwright.

First the page's own contact check (what turns a drag red) against independent references
(shapely, and covswarm.world.model.World.contact) on random convex polygons, on a console
whose feed is a fixed SwarmView (no network). Then end to end with real processes, no mocks:
one ``covswarm run --scenario live`` (3 robots; S holds still in the gap between the passage
arena's two obstacles until steered), a ``covswarm console`` per test, and the test's own
Zenoh session reading the coordinator's Domain broadcasts.
"""

from __future__ import annotations

import asyncio
import queue
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from aiohttp import web
from browser_pages import COLOUR, VIEWPORT, console, open_page
from live_runs import running_swarm, wait_until
from shapely.geometry import MultiPoint, Polygon

from covswarm.console.model import SwarmView
from covswarm.console.server import Console
from covswarm.protocol import Domain, World

pytestmark = pytest.mark.e2e

TEAM = 3


# -- the page's contact check, against references -------------------------------------------


class StillFeed:
    def __init__(self, view: SwarmView) -> None:
        self.view = view

    def drain(self, now: float) -> None:
        pass


@contextmanager
def still_console(view: SwarmView) -> Iterator[str]:
    """A Console over a fixed view, served from a thread (its own event loop: Playwright's
    sync API runs one in this thread) on a free loopback port."""
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(Console(StillFeed(view), None, token=None).app, access_log=None)
    ports: queue.Queue[int] = queue.Queue()

    def serve() -> None:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(runner.setup())
        loop.run_until_complete(web.TCPSite(runner, "127.0.0.1", 0).start())
        ports.put(runner.addresses[0][1])
        loop.run_forever()
        loop.run_until_complete(runner.cleanup())
        loop.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{ports.get(timeout=10)}/"
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=10)


def random_convex(rng: np.random.Generator, centre: np.ndarray, radius: float) -> np.ndarray:
    """A random convex CCW polygon (3..8 vertices) around ``centre``, whole mm (the wire's)."""
    while True:
        points = centre + rng.uniform(-radius, radius, size=(int(rng.integers(3, 9)), 2))
        shape = MultiPoint([tuple(p) for p in np.round(points, 3)]).convex_hull
        if isinstance(shape, Polygon) and shape.area > 1e-3:
            ring = np.array(shape.exterior.coords)[:-1]
            return ring if Polygon(ring).exterior.is_ccw else ring[::-1]


def test_the_pages_contact_check_agrees_with_shapely_and_the_world_model(browser) -> None:
    from covswarm.world.model import World as ModelWorld
    from covswarm.world.model import make_obstacle

    rng = np.random.default_rng(20)
    obstacles = [random_convex(rng, rng.uniform(-2, 2, 2), 0.5) for _ in range(6)]
    names = [f"block {k}" for k in range(6)]
    workspace = (-2.5, 2.5, -2.0, 2.0)
    message = World(
        seq=0,
        stamp=time.time(),
        obstacles=tuple(tuple(map(tuple, o)) for o in obstacles),
        workspace=workspace,
        names=tuple(names),
    )
    model = ModelWorld(
        workspace,
        tuple(
            make_obstacle(n, [list(p) for p in o]) for n, o in zip(names, obstacles, strict=True)
        ),
    )
    view = SwarmView("still")
    view.on_world(message)
    square = ((-0.2, -0.2), (0.2, -0.2), (0.2, 0.2), (-0.2, 0.2))
    view.on_domain(Domain(seq=0, stamp=time.time(), t=0.0, state="waiting", vertices=square,
                          velocities=[(0.0, 0.0)] * 4, kappa=2.0))  # fmt: skip
    polygons = [random_convex(rng, rng.uniform(-2.6, 2.6, 2), 0.4) for _ in range(300)]
    with still_console(view) as url:
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(url)
        page.wait_for_function("window.covswarm.world() !== null", timeout=15000)
        assert page.evaluate("document.body.dataset.obstaclesDrawn") == "6"
        pairs = page.evaluate(
            "(ps) => ps.map((p) => [window.covswarm.contact(p), window.covswarm.world()"
            ".obstacles.map((o) => window.covswarm.touches(p, o.polygon))])",
            [p.tolist() for p in polygons],
        )
        page.close()
    hits = 0
    for polygon, (named, touching) in zip(polygons, pairs, strict=True):
        shape = Polygon(polygon)
        assert touching == [shape.intersects(Polygon(o)) for o in obstacles], polygon
        assert named == model.contact(polygon), polygon
        hits += named is not None and named != "workspace"
    assert 30 < hits < 270  # both answers well represented


# -- end to end ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def swarm_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """(endpoint, swarm) of a running ``live`` mission; everything of it killed at the end."""
    folder = tmp_path_factory.mktemp("console-world")
    with running_swarm(
        folder, "--agents", str(TEAM), "--scenario", "live", "--duration", "300"
    ) as found:
        yield found


class DomainWatch:
    """The test's own Zenoh client: every Domain broadcast (arrival wall time, S)."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        import zenoh

        from covswarm.protocol import domain_key
        from covswarm.protocol.session import session_config

        self.domains: list[tuple[float, np.ndarray]] = []
        self.session = zenoh.open(session_config([endpoint]))

        def on_domain(sample: zenoh.Sample) -> None:
            d = Domain.decode(sample.payload.to_bytes())
            self.domains.append((time.time(), np.array(d.vertices)))

        self._sub = self.session.declare_subscriber(domain_key(swarm), on_domain)

    def latest(self) -> np.ndarray:
        return self.domains[-1][1]

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def watch(swarm_run: tuple[str, str]) -> Iterator[DomainWatch]:
    w = DomainWatch(*swarm_run)
    try:
        assert wait_until(lambda: len(w.domains) > 2, timeout=10)
        yield w
    finally:
        w.close()


def centroid(polygon: np.ndarray) -> np.ndarray:
    return np.array(Polygon(polygon).centroid.coords[0])


def test_the_arena_is_drawn_and_a_drag_into_an_obstacle_turns_red_and_is_refused(
    swarm_run, browser, watch: DomainWatch
) -> None:
    with console(*swarm_run) as url:
        page = open_page(browser, url)
        # The passage arena: its workspace and both obstacles, drawn filled and named.
        drawn = page.evaluate("window.covswarm.world()")
        assert drawn["workspace"] == [-2.591, 2.591, -1.829, 1.829]
        assert [o["name"] for o in drawn["obstacles"]] == ["obstacle 1", "obstacle 2"]
        assert page.evaluate("document.body.dataset.obstaclesDrawn") == "2"
        grey = page.evaluate(COLOUR, [0.0, 0.75])  # inside obstacle 1, below its label
        assert np.allclose(grey, [0x9A, 0xA5, 0xAD], atol=12), grey
        outside = page.evaluate(COLOUR, [-2.591 - 0.05, 0.0])  # just outside the workspace
        assert np.allclose(outside, [0xEC, 0xEF, 0xF1], atol=12), outside
        x, y = page.evaluate("window.covswarm.clientXY(0.0, 1.2)")
        page.mouse.move(x, y)
        assert page.inner_text("#hover") == "obstacle 1"

        # Drag S (held still in the gap) 0.3 m up: its top edge would enter obstacle 1.
        held = watch.latest().copy()
        c = centroid(held)
        x, y = page.evaluate(f"window.covswarm.clientXY({c[0]}, {c[1]})")
        scale = page.evaluate("window.covswarm.view()")["scale"]
        probe = [0.6, 0.5]  # inside the dragged S, outside the obstacle
        before = page.evaluate(COLOUR, probe)
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x, y - 0.3 * scale, steps=10)
        assert page.evaluate("window.covswarm.hooks.dragContact") == "obstacle 1"
        during = page.evaluate(COLOUR, probe)
        assert during[0] - during[2] > before[0] - before[2] + 25, (before, during)
        assert "obstacle 1" in page.inner_text("#steer-result")
        page.mouse.up()
        reply = page.evaluate("window.covswarm.hooks.lastReply")
        assert reply == {
            "accepted": False,
            "reason": "obstacle: S would touch obstacle 'obstacle 1'",
            "local": True,
        }
        shown = page.inner_text("#steer-result")
        assert shown.startswith("refused: obstacle: S would touch obstacle 'obstacle 1'"), shown
        after = page.evaluate(COLOUR, probe)
        assert abs((after[0] - after[2]) - (before[0] - before[2])) < 10  # red gone

        # The coordinator checks again: the same request sent past the page's check.
        request = page.evaluate("window.covswarm.hooks.lastRequest")
        assert request["kind"] == "translate" and request["dy"] == pytest.approx(0.3, abs=0.01)
        reply = page.evaluate("(r) => window.covswarm.steer(r)", request)
        assert not reply["accepted"] and reply["reason"].startswith("obstacle: S would touch")
        assert "'obstacle 1' ([-0.3, 0.3] x [0.45, 1.83] m) at t = " in reply["reason"], reply
        shown = page.inner_text("#steer-result")
        assert shown.startswith("refused: obstacle") and "obstacle 1" in shown, shown
        time.sleep(0.5)
        assert np.abs(watch.latest() - held).max() < 1e-9  # S never moved
        page.close()


def test_go_to_gets_a_route_that_is_drawn_and_S_follows_it(
    swarm_run, browser, watch: DomainWatch
) -> None:
    with console(*swarm_run) as url:
        page = open_page(browser, url)
        start = centroid(watch.latest())
        # A goal inside obstacle 1: the planner (the coordinator) says there is no way.
        page.click("#goto")
        x, y = page.evaluate("window.covswarm.clientXY(0.0, 1.2)")
        page.mouse.click(x, y)
        page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=10000)
        reply = page.evaluate("window.covswarm.hooks.lastReply")
        assert not reply["accepted"] and reply["reason"].startswith("no-path"), reply
        assert page.inner_text("#steer-result").startswith("refused: no-path")
        assert page.evaluate("window.covswarm.state().route") is None
        page.evaluate("window.covswarm.hooks.lastReply = null")

        goal = start + [1.5, 0.0]  # beyond the obstacles, the arena's right part
        page.click("#goto")
        assert page.evaluate("window.covswarm.gotoMode()")
        x, y = page.evaluate(f"window.covswarm.clientXY({goal[0]}, {goal[1]})")
        page.mouse.click(x, y)
        page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=10000)
        request, reply = page.evaluate(
            "[window.covswarm.hooks.lastRequest, window.covswarm.hooks.lastReply]"
        )
        assert np.allclose(request["goal"], goal, atol=0.02), request
        assert reply["accepted"], reply
        route = np.array(reply["route"])[:, :2]  # stops [x, y, scale]
        assert len(route) >= 2 and np.allclose(route[-1], request["goal"], atol=0.01), route
        assert np.allclose(route[0], start, atol=0.01), route
        assert not page.evaluate("window.covswarm.gotoMode()")
        assert page.inner_text("#steer-result").startswith("accepted goto")
        # Drawn, on this page and in every frame (a page opened later draws it too).
        page.wait_for_function(
            f"document.body.dataset.routePoints === '{len(route)}'", timeout=5000
        )
        state_route = page.evaluate("window.covswarm.state().route")
        assert state_route is not None
        assert np.allclose(np.array(state_route["waypoints"])[:, :2], route, atol=1e-3)
        mid = (route[0] + route[1]) / 2
        purple = page.evaluate(COLOUR, mid.tolist())
        assert purple[2] - purple[1] > 25, purple  # the route's line (#8e44ad) crosses there
        # S follows the route to the goal.
        assert wait_until(
            lambda: np.linalg.norm(centroid(watch.latest()) - route[-1]) < 0.01,
            timeout=reply["duration"] + 10,
        ), (centroid(watch.latest()), route[-1])
        page.close()
