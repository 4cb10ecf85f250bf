"""The operator console end to end: real processes, real Zenoh, real Chromium, no mocks.

One ``covswarm run`` (3 robots, passage, long mission) serves the whole module; each test
starts its own ``covswarm console`` on it and drives the page with Playwright and Debian's
chromium. What the coordinator does is read off the wire by a Zenoh session of the test's
own (the Domain broadcasts), what the robots do from their poses.
"""

from __future__ import annotations

import json
import secrets
import socket
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from browser_pages import console
from live_runs import launch, new_swarm, running_swarm, wait_until

from covswarm.deploy.plan import covswarm_argv

pytestmark = pytest.mark.e2e

TEAM = 3


@pytest.fixture(scope="module")
def swarm_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """(endpoint, swarm) of a running mission; everything of it killed at the end."""
    folder = tmp_path_factory.mktemp("console")
    with running_swarm(
        folder, "--agents", str(TEAM), "--scenario", "passage", "--duration", "300"
    ) as found:
        yield found


class DomainWatch:
    """The test's own Zenoh client: every Domain broadcast (arrival time, S) and poses."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        import zenoh

        from covswarm.protocol import Domain, Pose, all_poses_selector, domain_key
        from covswarm.protocol.session import session_config

        self.domains: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.poses: dict[int, tuple[float, float]] = {}
        self.session = zenoh.open(session_config([endpoint]))

        def on_domain(sample: zenoh.Sample) -> None:
            d = Domain.decode(sample.payload.to_bytes())
            self.domains.append((time.time(), np.array(d.vertices), np.array(d.velocities)))

        def on_pose(sample: zenoh.Sample) -> None:
            p = Pose.decode(sample.payload.to_bytes())
            self.poses[p.id] = (p.x, p.y)

        self._subs = [
            self.session.declare_subscriber(domain_key(swarm), on_domain),
            self.session.declare_subscriber(all_poses_selector(swarm), on_pose),
        ]

    def latest(self) -> np.ndarray:
        return self.domains[-1][1]

    def robots_mean(self) -> np.ndarray:
        return np.mean(list(self.poses.values()), axis=0)

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def watch(swarm_run: tuple[str, str]) -> Iterator[DomainWatch]:
    w = DomainWatch(*swarm_run)
    try:
        assert wait_until(lambda: len(w.domains) > 2 and len(w.poses) == TEAM, timeout=10)
        yield w
    finally:
        w.close()


def get(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def post_json(url: str, body: bytes, headers: dict[str, str] | None = None) -> tuple[int, dict]:
    request = urllib.request.Request(
        url, data=body, headers={"Content-Type": "application/json", **(headers or {})},
        method="POST",
    )  # fmt: skip
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


# The page has drawn the coordinator's world (it then fits the arena in the view, once).
WORLD_DRAWN = "window.covswarm.world() !== null && window.covswarm.view().ready"


def centroid(polygon: np.ndarray) -> np.ndarray:
    x, y = polygon[:, 0], polygon[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2
    return np.array(
        [((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]
    ) / (6 * area)


def test_page_shows_the_live_swarm_and_api_state_has_its_shape(swarm_run, browser) -> None:
    with console(*swarm_run) as url:
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(url)
        page.wait_for_function(f"document.body.dataset.robotsDrawn === '{TEAM}'", timeout=15000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)  # the view is set: on the arena
        assert page.inner_text("#alive-robots") == str(TEAM)
        assert page.inner_text("#alive-agents") == str(TEAM)
        assert page.inner_text("#state") == "running"
        # The view opens on the arena (the coordinator's World): the whole workspace in
        # view, centred, and S in it.
        state = page.evaluate("window.covswarm.state()")
        view = page.evaluate("window.covswarm.view()")
        xmin, xmax, ymin, ymax = page.evaluate("window.covswarm.world().workspace")
        assert (view["cx"], view["cy"]) == pytest.approx(((xmin + xmax) / 2, (ymin + ymax) / 2))
        for x, y in [(xmin, ymin), (xmax, ymax), *state["polygon"]]:
            px, py = page.evaluate(f"window.covswarm.clientXY({x}, {y})")
            assert 0 <= px <= 1100 - 320 and 0 <= py <= 700, (x, y)  # the map, left of the aside
        # State frames reach the page at >= 10 Hz.
        first = page.evaluate("window.covswarm.hooks.frames")
        time.sleep(3.0)
        assert page.evaluate("window.covswarm.hooks.frames") - first >= 30
        page.close()

        status, raw = get(url.rstrip("/") + "/api/state")
        assert status == 200
        doc = json.loads(raw)
        assert doc["state"] == "running" and doc["t"] > 0
        assert len(doc["polygon"]) >= 3 and all(len(v) == 2 for v in doc["polygon"])
        assert sorted(r["id"] for r in doc["robots"]) == list(range(TEAM))
        for robot in doc["robots"]:
            assert {"id", "x", "y", "theta", "error"} <= set(robot)
            assert all(isinstance(robot[k], float | int) for k in ("x", "y", "theta", "error"))
            assert 0.0 <= robot["error"] < 1.0
        assert doc["alive"] == {"agents": TEAM, "robots": TEAM, "coordinator": True}
        # e_a is the norm of the per-robot distances to the centroids (within the time
        # between the coordinator's sample and ours).
        assert len(doc["error_history"]) > 0


def test_dragging_S_moves_the_coordinators_S_and_then_the_robots(
    swarm_run, browser, watch: DomainWatch
) -> None:
    with console(*swarm_run) as url:
        # S first to the left room (a goto, planned around the obstacles, wherever the script
        # has taken S), where 0.4 m down is free space.
        goto(url, LEFT_ROOM + [0.0, 0.4])
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(url)
        page.wait_for_function(f"document.body.dataset.robotsDrawn === '{TEAM}'", timeout=15000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)  # the view is set: on the arena
        before = centroid(watch.latest())
        robots_before = watch.robots_mean()
        handles = page.evaluate("window.covswarm.handles()")
        x, y = page.evaluate(f"window.covswarm.clientXY({handles['c'][0]}, {handles['c'][1]})")
        drop = 0.4  # m, down: free space below S (which holds still at the goto's goal)
        scale = page.evaluate("window.covswarm.view()")["scale"]
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x, y + drop * scale, steps=10)
        released = time.time()
        page.mouse.up()
        page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=5000)
        reply = page.evaluate("window.covswarm.hooks.lastReply")
        assert reply["accepted"], reply
        assert page.inner_text("#steer-result").startswith("accepted")

        # The coordinator's S starts moving down (its vertices' mean velocity) ...
        def moving_down() -> list[float]:
            return [t for t, _, v in list(watch.domains) if t > released and v[:, 1].mean() < -1e-3]

        assert wait_until(lambda: moving_down(), timeout=5)
        assert moving_down()[0] - released < 2.0
        # ... and ends where the drag put it, then the robots follow.
        wait_until(lambda: centroid(watch.latest())[1] < before[1] - drop + 0.01, timeout=15)
        assert centroid(watch.latest())[1] == pytest.approx(before[1] - drop, abs=0.02)
        assert wait_until(lambda: watch.robots_mean()[1] < robots_before[1] - 0.3, timeout=20)
        page.close()


# The middle of the passage arena's left room (x from the wall at -2.591 m to the obstacles
# at -0.3 m), m.
LEFT_ROOM = np.array([-1.45, 0.0])


def goto(url: str, goal: np.ndarray) -> None:
    """Take S's centroid to ``goal`` by a goto (POST /api/steer) and wait until it is there."""
    status, reply = post_json(
        url.rstrip("/") + "/api/steer",
        json.dumps({"kind": "goto", "goal": [float(v) for v in goal]}).encode(),
    )
    assert status == 200 and reply["accepted"], reply
    time.sleep(reply["duration"] + 0.5)


def same_polygon(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Every vertex of each polygon is within ``tol`` of a vertex of the other."""
    d = np.linalg.norm(np.asarray(a)[:, None, :] - np.asarray(b)[None, :, :], axis=2)
    return bool(d.min(axis=1).max() < tol and d.min(axis=0).max() < tol)


def test_S_dragged_while_it_moves_ends_where_it_was_dropped(
    swarm_run, browser, watch: DomainWatch
) -> None:
    """The coordinator brakes a moving S before the next motion: a relative move sent for a
    drag of a moving S started from where S stopped and took it past the drop (0.38 m in an
    operator's run). The page sends the outline dropped, and S ends on it."""
    with console(*swarm_run) as url:
        goto(url, LEFT_ROOM)
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(url)
        page.wait_for_function(f"document.body.dataset.robotsDrawn === '{TEAM}'", timeout=15000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)
        status, reply = post_json(  # S sets off up, slowly
            url.rstrip("/") + "/api/steer",
            json.dumps({"kind": "translate", "dx": 0.0, "dy": 0.5, "duration": 3.0}).encode(),
        )
        assert status == 200 and reply["accepted"], reply
        page.wait_for_function(
            "window.covswarm.state().velocities.some(v => Math.abs(v[1]) > 0.1)", timeout=5000
        )
        page.evaluate("window.covswarm.hooks.lastReply = null")
        handles = page.evaluate("window.covswarm.handles()")
        x, y = page.evaluate(f"window.covswarm.clientXY({handles['c'][0]}, {handles['c'][1]})")
        scale = page.evaluate("window.covswarm.view()")["scale"]
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x, y + 0.3 * scale, steps=10)  # 0.3 m down
        page.mouse.up()
        page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=5000)
        request, reply = page.evaluate(
            "[window.covswarm.hooks.lastRequest, window.covswarm.hooks.lastReply]"
        )
        assert reply["accepted"], (request, reply)
        time.sleep(reply["duration"] + 1.5)  # its brake, its motion, and it holds
        assert centroid(watch.latest())[1] == pytest.approx(handles["c"][1] - 0.3, abs=0.02)
        assert request["kind"] == "polygon"  # the outline dropped, which S is now
        assert same_polygon(watch.latest(), np.array(request["polygon"]), tol=0.01)
        page.close()


def test_rotate_scale_and_vertex_handles_steer_what_was_dragged(
    swarm_run, browser, watch: DomainWatch
) -> None:
    from shapely.geometry import Polygon

    with console(*swarm_run) as url:
        # S to the middle of the left room first, where a quarter turn and a scaling by 1.25
        # stay clear of the walls and obstacles (the coordinator refuses what would not).
        goto(url, LEFT_ROOM)
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(url)
        page.wait_for_function(f"document.body.dataset.robotsDrawn === '{TEAM}'", timeout=15000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)  # the view is set: on the arena

        def gesture(start, end, says: str = "release to send") -> tuple[dict, dict]:
            page.evaluate("window.covswarm.hooks.lastReply = null")
            x0, y0 = page.evaluate(f"window.covswarm.clientXY({start[0]}, {start[1]})")
            x1, y1 = page.evaluate(f"window.covswarm.clientXY({end[0]}, {end[1]})")
            page.mouse.move(x0, y0)
            page.mouse.down()
            page.mouse.move(x1, y1, steps=20)
            assert page.inner_text("#steer-result") == says  # before the release
            page.mouse.up()
            page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=5000)
            request, reply = page.evaluate(
                "[window.covswarm.hooks.lastRequest, window.covswarm.hooks.lastReply]"
            )
            assert reply["accepted"], (request, reply)
            time.sleep(reply["duration"] + 0.5)  # S gets there and holds
            return request, reply

        # A quarter turn clockwise: the knob above the centroid dragged to its right.
        before, h = watch.latest().copy(), page.evaluate("window.covswarm.handles()")
        c, knob = np.array(h["c"]), np.array(h["rotate"])
        request, _ = gesture(knob, c + [np.linalg.norm(knob - c), 0.0])
        assert request["kind"] == "rotate" and request["angle"] == pytest.approx(
            -np.pi / 2, abs=0.03
        )
        turn = np.array([[0.0, 1.0], [-1.0, 0.0]])  # rotation by -pi/2
        assert same_polygon(watch.latest(), c + (before - c) @ turn.T, tol=0.03)

        # The corner handle dragged 1.25 times as far from the centroid.
        before, h = watch.latest().copy(), page.evaluate("window.covswarm.handles()")
        c, corner = np.array(h["c"]), np.array(h["scale"])
        request, _ = gesture(corner, c + 1.25 * (corner - c))
        assert request["kind"] == "scale" and request["factor"] == pytest.approx(1.25, abs=0.02)
        assert same_polygon(watch.latest(), c + request["factor"] * (before - c), tol=0.02)

        # A vertex dragged through S to beyond the opposite one: the page stops it where S
        # is still convex, and the coordinator's S becomes exactly that polygon.
        polygon = np.array(page.evaluate("window.covswarm.state().polygon"))
        v0, opposite = polygon[0], polygon[2]
        held = "S stays convex: the vertex holds its last convex position; release to send"
        request, _ = gesture(v0, opposite + 0.2 * (opposite - v0), held)
        assert request["kind"] == "polygon"
        sent = np.array(request["polygon"])
        shape = Polygon(sent)
        assert shape.is_valid and shape.area == pytest.approx(shape.convex_hull.area, rel=1e-9)
        assert np.linalg.norm(sent[0] - v0) > 0.05  # it moved ...
        assert np.linalg.norm(sent[0] - opposite) > 0.1  # ... but not as far as the mouse
        assert same_polygon(watch.latest(), sent, tol=0.01)
        page.close()


def test_refused_and_malformed_requests_show_why_and_never_move_S(
    swarm_run, browser, watch: DomainWatch
) -> None:
    with console(*swarm_run) as url:
        api = url.rstrip("/") + "/api/steer"
        # Take S over from the script and let it settle, so that S holds still.
        status, reply = post_json(
            api, json.dumps({"kind": "translate", "dx": 0.0, "dy": 0.05}).encode()
        )
        assert status == 200 and reply["accepted"], reply
        time.sleep(reply["duration"] + 0.5)
        held = watch.latest().copy()
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(url)
        page.wait_for_function("window.covswarm.state() !== null", timeout=15000)
        bowtie = [[-0.5, -0.2], [0.5, 0.2], [0.5, -0.2], [-0.5, 0.2]]
        reply = page.evaluate("(p) => window.covswarm.steer({kind: 'polygon', polygon: p})", bowtie)
        assert not reply["accepted"]
        shown = page.inner_text("#steer-result")
        assert shown.startswith("refused:") and "self-intersecting" in shown
        # Another site's page cannot steer through the operator's browser.
        forged = urllib.request.Request(
            api, data=b'{"kind": "translate", "dx": 1, "dy": 0}', method="POST",
            headers={"Content-Type": "application/json", "Origin": "http://evil.example"},
        )  # fmt: skip
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(forged, timeout=10)
        assert refused.value.code == 403
        for bad in (b"{", b'{"kind": "translate", "dx": NaN, "dy": 0}', b'{"kind": "warp"}'):
            status, reply = post_json(api, bad)
            assert status == 400 and not reply["accepted"] and reply["reason"], bad
        page.wait_for_function(
            "document.querySelectorAll('#steer-log li.refused').length >= 3", timeout=5000
        )
        time.sleep(1.0)
        assert np.abs(watch.latest() - held).max() < 1e-9
        page.close()


def test_a_console_off_the_default_address_needs_its_token(swarm_run, browser) -> None:
    with console(*swarm_run, "--host", "127.0.0.2") as url:
        assert "?token=" in url
        base, token = url.split("?token=")
        state = base + "api/state"
        assert get(state)[0] == 403
        assert get(state + "?token=" + "x" * len(token))[0] == 403
        status, raw = get(state, {"Authorization": f"token {token}"})
        assert status == 200 and json.loads(raw)["console"]["refused_requests"] == 2
        assert get(base)[0] == 403  # the page itself
        assert post_json(base + "api/steer", b'{"kind": "translate", "dx": 1, "dy": 0}')[0] == 403
        # Without the token a browser gets nothing, not even the stream.
        stranger = browser.new_page()
        assert stranger.goto(base).status == 403
        stranger.close()
        # With the printed URL the page works: the token moves into a cookie.
        page = browser.new_page()
        page.goto(url)
        assert "token" not in page.url
        page.wait_for_function(f"document.body.dataset.robotsDrawn === '{TEAM}'", timeout=15000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)  # the view is set: on the arena
        page.close()


def test_a_secured_console_joins_with_the_credentials_and_only_with_them(
    tmp_path: Path, browser
) -> None:
    import zenoh

    from covswarm.protocol import Domain, Pose, domain_key, pose_key
    from covswarm.protocol.security import make_test_credentials
    from covswarm.protocol.session import session_config

    secure = make_test_credentials(tmp_path / "secure")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        endpoint = f"tls/127.0.0.1:{probe.getsockname()[1]}"
    swarm = f"e2e-{secrets.token_hex(4)}"
    square = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))
    with (
        zenoh.open(session_config(None, [endpoint], "router", secure=secure)),
        # The Domain is the coordinator's to publish (protocol.access): the test acts as it.
        zenoh.open(session_config([endpoint], secure=secure, role="coordinator")) as member,
        zenoh.open(session_config([endpoint], secure=secure, role="robot", id=9)) as robot_9,
        console(endpoint, swarm, "--secure", str(secure)) as url,
    ):
        # Its steering requests carry the console's certificate: on loopback too, only the
        # holder of the printed URL's token may use it (another local user may not).
        assert url.startswith("http://127.0.0.1:") and "?token=" in url
        base, token = url.split("?token=")
        signed = {"Authorization": f"token {token}"}
        domain = Domain(seq=0, stamp=time.time(), t=1.0, state="running", vertices=square,
                        velocities=[(0.0, 0.0)] * 4, kappa=2.0)  # fmt: skip

        def state() -> dict:
            status, raw = get(base + "api/state", signed)
            assert status == 200, raw
            return json.loads(raw)

        def polygon_seen() -> bool:
            member.put(domain_key(swarm), domain.encode())
            return state()["polygon"] == [list(v) for v in square]

        assert wait_until(polygon_seen, timeout=10, period=0.2)
        assert get(base + "api/state")[0] == 403
        steer = b'{"kind": "translate", "dx": 1, "dy": 0}'
        assert post_json(base + "api/steer", steer)[0] == 403  # never reaches the swarm
        # Steering goes over the same secured session: with no coordinator, nobody answers.
        status, reply = post_json(base + "api/steer", steer, signed)
        assert status == 504 and "no coordinator" in reply["reason"]
        # Robot 9's certificate puts only robot/9/pose, and a pose there saying it is robot 0
        # is dropped: the console shows robot 0 where robot 0's own key says, or not at all.
        forged = Pose(id=0, x=0.5, y=0.5, theta=0.0, stamp=time.time(), seq=1)

        def forgery_dropped() -> bool:
            robot_9.put(pose_key(swarm, 9), forged.encode())
            return state()["dropped"].get("wrong_id", 0) > 0

        assert wait_until(forgery_dropped, timeout=10, period=0.2)
        assert state()["robots"] == []
        # The page offers no steering then (S drawn, no handles): a drag sends nothing.
        page = browser.new_page(viewport={"width": 900, "height": 600})
        page.goto(url)
        page.wait_for_function("window.covswarm.state() && window.covswarm.view().ready")
        x, y = page.evaluate("window.covswarm.clientXY(0.5, 0.5)")
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 60, y, steps=5)
        page.mouse.up()
        assert page.evaluate("window.covswarm.hooks.lastRequest") is None
        assert page.inner_text("#steer-result") == "no coordinator: S cannot be steered"
        page.close()

        wrong = make_test_credentials(tmp_path / "wrong", ids=[])  # another lab's CA
        for extra, said in (
            (["--secure", str(wrong)], "cannot reach the swarm"),  # the router refuses it
            ([], "a tls/ endpoint needs --secure DIR"),  # refused before any session
        ):
            outsider = subprocess.run(
                [*covswarm_argv(), "console", "--connect", endpoint, "--swarm", swarm,
                 "--port", "0", *extra],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            assert outsider.returncode != 0 and "http://" not in outsider.stdout
            assert said in outsider.stderr, outsider.stderr


def listening(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


# Mean red minus blue (0-255) over a 15 x 15 pixel patch of the map around a world point.
TINT = """([x, y]) => {
  const map = document.getElementById("map"), box = map.getBoundingClientRect();
  const [cx, cy] = window.covswarm.clientXY(x, y), dpr = window.devicePixelRatio || 1;
  const px = Math.round((cx - box.left) * dpr) - 7, py = Math.round((cy - box.top) * dpr) - 7;
  const data = map.getContext("2d").getImageData(px, py, 15, 15).data;
  let tint = 0;
  for (let i = 0; i < data.length; i += 4) tint += data[i] - data[i + 2];
  return tint / (data.length / 4);
}"""


def test_covswarm_run_console_serves_the_page_and_stops_with_the_run(
    browser, tmp_path: Path
) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    swarm, out = new_swarm(), tmp_path / "run"
    with launch(
        out, "--agents", "2", "--scenario", "formation", "--duration", "10", "--console",
        "--console-port", str(port), swarm=swarm,
    ) as launcher:  # fmt: skip
        assert wait_until(lambda: (out / "launch.json").exists(), timeout=60)
        url = json.loads((out / "launch.json").read_text())["console"]
        assert url == f"http://127.0.0.1:{port}/"
        assert wait_until(lambda: listening(port), timeout=60)
        page = browser.new_page()
        page.goto(url)
        page.wait_for_function("document.body.dataset.robotsDrawn === '2'", timeout=60000)
        page.wait_for_function("document.getElementById('state').textContent === 'running'")
        # The formation's bump is shaded inside S: more orange at its mean than far from it.
        page.wait_for_function("window.covswarm.hooks.shaded > 0", timeout=10000)
        page.wait_for_function(WORLD_DRAWN, timeout=5000)
        state = page.evaluate("window.covswarm.state()")
        (bump,) = state["density"]["bumps"]
        polygon = np.array(state["polygon"])
        far = max(polygon, key=lambda v: np.hypot(*(v - bump["mean"])))
        far = far + 0.15 * (centroid(polygon) - far)  # inside S, away from its edge
        near_tint, far_tint = (
            page.evaluate(TINT, list(map(float, q))) for q in (bump["mean"], far)
        )
        assert near_tint > far_tint + 20, (near_tint, far_tint)
        page.close()
        assert launcher.wait(timeout=120) == 0, (tmp_path / "run.launcher.log").read_text()
        assert not listening(port)  # the console went with the run
        resources = json.loads((out / "resources.json").read_text())
        assert len(resources["cpu_percent_of_core"]["console"]) == 1


def test_a_secured_run_console_needs_the_token_the_launcher_prints(tmp_path: Path) -> None:
    """``covswarm run --secure DIR --console``: the console steers with the swarm's
    credentials, so on 127.0.0.1 too it serves only requests with its token. The launcher
    prints the URL with it (one line); the token reaches the console in an owner-only file,
    never on a command line or in a log, and goes with the run."""
    from covswarm.protocol.security import make_test_credentials

    secure = make_test_credentials(tmp_path / "secure", ids=range(2))
    swarm, out = new_swarm(), tmp_path / "run"
    launcher_log = tmp_path / "run.launcher.log"
    with launch(
        out, "--agents", "2", "--scenario", "formation", "--duration", "15", "--console",
        "--console-port", "0", "--secure", str(secure), swarm=swarm,
    ) as launcher:  # fmt: skip
        assert wait_until(lambda: (out / "launch.json").exists(), timeout=60)
        launched = json.loads((out / "launch.json").read_text())
        base, token_file = launched["console"], Path(launched["console_token_file"])
        printed = [
            line for line in launcher_log.read_text().splitlines() if "operator console" in line
        ]
        assert printed and printed[0].endswith(f"{base}?token={token_file.read_text().strip()}")
        token = printed[0].rpartition("?token=")[2]
        assert token_file.stat().st_mode & 0o077 == 0
        assert token not in json.dumps(launched)  # not in its argv either
        port = int(base.rstrip("/").rpartition(":")[2])
        assert wait_until(lambda: listening(port), timeout=60)
        signed = {"Authorization": f"token {token}"}
        assert wait_until(lambda: get(base + "api/state", signed)[0] == 200, timeout=30)
        assert get(base + "api/state")[0] == 403
        steer = b'{"kind": "translate", "dx": 0.1, "dy": 0}'
        assert post_json(base + "api/steer", steer)[0] == 403
        # The printed URL opens the page (its token moves into a cookie, as in a browser).
        browser_like = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
        with browser_like.open(base + f"?token={token}", timeout=10) as page:
            assert page.status == 200 and b"<canvas" in page.read()
        assert launcher.wait(timeout=120) == 0, launcher_log.read_text()
    assert not token_file.exists()
    assert token not in (out / "logs" / "console-0.log").read_text()
