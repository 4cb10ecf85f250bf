"""The console's side of the world (issue 20, item 7), without a network: the arena the page
fetches (versioned, sent again only when it changes), the route of an accepted goto, and
the web app's ``/api/world`` and steering answers (aiohttp's test server on loopback, the
Zenoh feed replaced by a bare SwarmView, the coordinator by a function)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from aiohttp.test_utils import TestClient, TestServer

from covswarm.console.model import SwarmView
from covswarm.console.server import Console
from covswarm.protocol import Domain, MapImage, Status, World
from covswarm.protocol.steering import SteerReply

SCENARIOS = Path(__file__).parents[1] / "scenarios"
WALL = ((-0.3, 0.45), (0.3, 0.45), (0.3, 1.8), (-0.3, 1.8))
WEDGE = ((1.0, -1.0), (2.0, -1.0), (1.5, -0.2))


def world(seq: int = 0, obstacles=(WALL, WEDGE), names=("wall", "wedge"), workspace=None):
    return World(
        seq=seq,
        stamp=1.7e9,
        obstacles=obstacles,
        workspace=(-2.5, 2.5, -1.8, 1.8) if workspace is None else workspace,
        names=names,
    )


def test_the_world_document_carries_the_arena_and_its_version() -> None:
    view = SwarmView("s")
    assert view.world_document() is None
    assert view.snapshot(now=0.0, wall=1.7e9)["world"] is None
    view.on_world(world())
    doc = view.world_document()
    assert doc == {
        "version": 1,
        "map": None,  # until the coordinator answers the map query with a picture
        "workspace": [-2.5, 2.5, -1.8, 1.8],
        "obstacles": [
            {"name": "wall", "polygon": [list(p) for p in WALL]},
            {"name": "wedge", "polygon": [list(p) for p in WEDGE]},
        ],
    }
    assert json.loads(json.dumps(doc)) == doc  # JSON-ready
    assert view.snapshot(now=0.0, wall=1.7e9)["world"] == {"version": 1, "obstacles": 2}


def test_the_version_changes_only_when_the_arena_does() -> None:
    view = SwarmView("s")
    for seq in range(5):  # the coordinator repeats the same World every second
        view.on_world(world(seq=seq))
    assert view.world_document()["version"] == 1
    view.on_world(world(obstacles=(WALL,), names=("wall",)))
    assert view.world_document()["version"] == 2
    assert [o["name"] for o in view.world_document()["obstacles"]] == ["wall"]
    view.on_world(world(obstacles=(WALL,), names=("renamed",)))
    assert view.world_document()["version"] == 3
    view.on_world(world(obstacles=(WALL,), names=("renamed",), workspace=(-3, 3, -2, 2)))
    doc = view.world_document()
    assert doc["version"] == 4 and doc["workspace"] == [-3.0, 3.0, -2.0, 2.0]


def test_a_world_without_workspace_or_names_gets_the_defaults() -> None:
    view = SwarmView("s")
    view.on_world(World(seq=0, stamp=1.7e9, obstacles=(WALL,)))
    doc = view.world_document()
    assert doc["workspace"] is None and doc["obstacles"][0]["name"] == "obstacle 1"


def goto_outcome(accepted: bool, route: Any, wall: float = 5.0) -> dict[str, Any]:
    return {
        "wall": wall,
        "request": {"kind": "goto", "goal": [1.6, 0.0]},
        "what": "goto (1.6, 0)",
        "accepted": accepted,
        "reason": "" if accepted else "no-path: enclosed",
        "duration": 9.5 if accepted else 0.0,
        "route": route,
    }


def test_an_accepted_goto_draws_its_route_until_another_request_takes_S() -> None:
    from shapely.geometry import Polygon

    view = SwarmView("s")
    # S a trapezoid: its area centroid (the shape's origin) is not its vertices' mean
    trapezoid = ((0.0, 0.0), (4.0, 0.0), (4.0, 1.0), (0.0, 3.0))
    view.on_domain(
        Domain(seq=0, stamp=1.7e9, t=3.0, state="running", vertices=trapezoid,
               velocities=[(0.0, 0.0)] * 4, kappa=2.0)
    )  # fmt: skip
    stops = [[3.0, 2.0, 1.0], [0.8, 0.1234567, 0.5], [1.6, 0.0, 1.0]]
    view.on_steering(goto_outcome(True, stops))
    route = view.snapshot(now=0.0, wall=1.7e9)["route"]
    c = Polygon(trapezoid).centroid
    assert route == {
        "goal": [1.6, 0.0],
        "waypoints": [[3.0, 2.0, 1.0], [0.8, 0.1235, 0.5], [1.6, 0.0, 1.0]],  # 0.1 mm
        "shape": [[round(x - c.x, 4), round(y - c.y, 4)] for x, y in trapezoid],
        "wall": 5.0,
        "duration": 9.5,
    }
    # A refused request leaves S (and the route it follows) as it was ...
    view.on_steering(goto_outcome(False, None, wall=6.0))
    view.on_steering({"wall": 7.0, "request": {"kind": "translate"}, "accepted": False})
    assert view.snapshot(now=0.0, wall=1.7e9)["route"]["wall"] == 5.0
    # ... an accepted one takes S off the route.
    view.on_steering({"wall": 8.0, "request": {"kind": "translate"}, "accepted": True})
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is None


class StillFeed:
    """A feed that hears nothing new: the view is whatever the test put in it; asked for
    the map's picture, it answers ``image`` (None: the coordinator has no map)."""

    def __init__(self, view: SwarmView, image: Any = None) -> None:
        self.view = view
        self.image = image
        self.map_queries = 0

    def drain(self, now: float) -> None:
        pass

    def fetch_map(self) -> tuple[bool, Any, str | None]:
        self.map_queries += 1
        return True, self.image, None


async def _ask(console: Console, *requests: tuple[str, str, bytes | None]) -> list[tuple[int, Any]]:
    answers = []
    async with TestClient(TestServer(console.app, host="127.0.0.1")) as client:
        for method, path, body in requests:
            response = await client.request(
                method,
                path,
                data=body,
                headers={"Content-Type": "application/json", "Host": "127.0.0.1"},
            )
            answers.append((response.status, await response.json()))
    return answers


def test_api_world_is_404_until_the_coordinator_sends_one_then_the_document() -> None:
    view = SwarmView("s")
    ((status, body),) = asyncio.run(
        _ask(Console(StillFeed(view), None, token=None), ("GET", "/api/world", None))
    )
    assert status == 404 and "no world" in body["error"]
    view.on_world(world())
    (world_answer, state_answer) = asyncio.run(
        _ask(
            Console(StillFeed(view), None, token=None),
            ("GET", "/api/world", None),
            ("GET", "/api/state", None),
        )
    )
    assert world_answer == (200, view.world_document())
    assert state_answer[1]["world"] == {"version": 1, "obstacles": 2}


def test_api_world_needs_the_token_like_every_route() -> None:
    view = SwarmView("s")
    view.on_world(world())
    console = Console(StillFeed(view), None, token="secret-token")
    ((status, body),) = asyncio.run(_ask(console, ("GET", "/api/world", None)))
    assert status == 403 and "obstacles" not in body


def test_a_steering_answer_carries_the_route_and_the_page_sees_it() -> None:
    view = SwarmView("s")
    asked = []

    def coordinator(request: Any) -> SteerReply:
        asked.append(request)
        if request.kind == "goto":
            return SteerReply(
                accepted=True, reason="", duration=9.5, route=((0.0, 0.0, 1.0), (1.6, 0.0, 0.5))
            )
        return SteerReply(accepted=False, reason="obstacle: S would touch wall at t = 3 s",
                          duration=0.0)  # fmt: skip

    console = Console(StillFeed(view), coordinator, token=None)
    goto, translate, state = asyncio.run(
        _ask(
            console,
            ("POST", "/api/steer", b'{"kind": "goto", "goal": [1.6, 0.0]}'),
            ("POST", "/api/steer", b'{"kind": "translate", "dx": 0.0, "dy": 1.0}'),
            ("GET", "/api/state", None),
        )
    )
    assert [r.kind for r in asked] == ["goto", "translate"]
    assert goto == (200, {"accepted": True, "reason": "", "duration": 9.5,
                          "route": [[0.0, 0.0, 1.0], [1.6, 0.0, 0.5]]})  # fmt: skip
    assert translate[1]["accepted"] is False and translate[1]["route"] is None
    assert translate[1]["reason"].startswith("obstacle: S would touch wall")
    document = state[1]
    assert document["route"]["waypoints"] == [[0.0, 0.0, 1.0], [1.6, 0.0, 0.5]]
    assert document["route"]["shape"] == []  # no Domain heard yet: S's shape unknown
    assert document["route"]["goal"] == [1.6, 0.0]
    assert [o["accepted"] for o in document["steering"]] == [True, False]


@pytest.mark.parametrize(
    "body",
    [
        b'{"kind": "goto"}',
        b'{"kind": "goto", "goal": [1.0]}',
        b'{"kind": "goto", "goal": [1.0, "a"]}',
        b'{"kind": "goto", "goal": [1.0, 2.0], "dx": 1.0}',
    ],
)
def test_a_malformed_goto_never_reaches_the_coordinator(body: bytes) -> None:
    def coordinator(request: Any) -> SteerReply:
        raise AssertionError(f"reached the coordinator: {request}")

    console = Console(StillFeed(SwarmView("s")), coordinator, token=None)
    ((status, answer),) = asyncio.run(_ask(console, ("POST", "/api/steer", body)))
    assert status == 400 and answer["accepted"] is False and answer["reason"], answer


def test_a_maps_world_reaches_the_page_whole_and_small() -> None:
    """The lab map's pieces (scenarios/lab.yaml through the wire) are every obstacle drawn,
    each exactly as broadcast, in a document of a few kB."""
    from pathlib import Path

    from covswarm.mission.scenario_files import load_scenario
    from covswarm.world.wire import to_message

    scenario = load_scenario(Path(__file__).parents[1] / "scenarios" / "lab-route.toml")
    message = World.decode(to_message(scenario.world, seq=3, stamp=1.7e9).encode())
    view = SwarmView("s")
    view.on_world(message)
    doc = view.world_document()
    assert len(doc["obstacles"]) == len(message.obstacles) >= 4
    for drawn, polygon, name in zip(
        doc["obstacles"], message.obstacles, message.names, strict=True
    ):
        assert drawn == {"name": name, "polygon": [list(p) for p in polygon]}
    assert doc["workspace"] == list(message.workspace)
    assert len(json.dumps(doc, separators=(",", ":"))) < 8_000


def domain(dx: float = 0.0) -> Domain:
    """S a trapezoid (its area centroid is not its vertices' mean), moved by dx."""
    vertices = [(x + dx, y) for x, y in ((0.0, 0.0), (4.0, 0.0), (4.0, 1.0), (0.0, 3.0))]
    return Domain(seq=0, stamp=1.7e9, t=3.0, state="running", vertices=vertices,
                  velocities=[(0.0, 0.0)] * 4, kappa=2.0)  # fmt: skip


def status(route=None, state: str = "running") -> Status:
    return Status(stamp=1.7e9, t=3.0, state=state, error=0.1, alive_agents=3, alive_robots=3,
                  route=route)  # fmt: skip


def test_a_route_from_any_client_is_drawn_while_the_status_tells_it() -> None:
    view = SwarmView("s")
    view.on_status(status())
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is None
    view.on_domain(domain())
    stops = ((0.0, 0.0, 1.0), (0.8, 0.1, 0.5, 0.3), (1.6, 0.0, 0.5))  # 3 or 4 numbers a stop
    view.on_status(status(route=stops))  # a goto another client sent
    route = view.snapshot(now=0.0, wall=1.7e9)["route"]
    assert route["waypoints"] == [[0.0, 0.0, 1.0], [0.8, 0.1, 0.5, 0.3], [1.6, 0.0, 0.5]]
    assert route["goal"] == [1.6, 0.0]
    from shapely.geometry import Polygon

    centroid = Polygon(domain().vertices).centroid
    expected = np.array(domain().vertices) - [centroid.x, centroid.y]
    assert np.allclose(route["shape"], expected, atol=1e-4)
    assert route["wall"] is None and route["duration"] is None
    # Repeated: the same route, its shape kept (S moves on along it).
    view.on_domain(domain(dx=1.0))
    view.on_status(status(route=stops))
    assert view.snapshot(now=0.0, wall=1.7e9)["route"]["shape"] == route["shape"]
    view.on_status(status())  # S arrived (or another request took it elsewhere)
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is None


def test_a_route_from_this_consoles_reply_outlives_an_older_status() -> None:
    view = SwarmView("s")
    view.on_steering(goto_outcome(True, [[0.0, 0.0, 1.0], [1.6, 0.0, 0.5]]))
    view.on_status(status())  # sent before the goto was accepted, heard after the reply
    assert view.snapshot(now=0.0, wall=1.7e9)["route"]["wall"] == 5.0
    view.on_status(status(route=((0.0, 0.0, 1.0), (1.6, 0.0, 0.5))))  # confirmed
    assert view.snapshot(now=0.0, wall=1.7e9)["route"]["wall"] == 5.0  # the same route
    view.on_status(status())  # then the first Status without it ends it
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is None
    # A reply's route the coordinator never confirms (S arrived within 0.5 s) goes too.
    view.on_steering(goto_outcome(True, [[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]]))
    view.on_status(status())
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is not None
    view.on_status(status())
    assert view.snapshot(now=0.0, wall=1.7e9)["route"] is None


def lab_picture():
    from covswarm.world.map_image import map_image
    from covswarm.world.maps import read_map

    return MapImage.decode(map_image(read_map(SCENARIOS / "lab.yaml")).encode())


def test_the_map_picture_is_asked_once_per_arena_and_placed_in_the_world() -> None:
    view = SwarmView("s")
    assert view.map_wanted() is None  # no arena yet
    view.on_world(world())
    assert view.map_wanted() == 1
    picture = lab_picture()
    view.on_map(1, picture)
    assert view.map_wanted() is None and view.map_png == picture.png
    doc = view.world_document()
    assert doc["version"] == 2  # the page fetches the arena again, now with its map
    assert doc["map"] == {"origin": [-5.0, -3.0], "resolution": 0.05, "width": 200,
                          "height": 120}  # fmt: skip
    view.on_world(world(seq=1))  # the same arena repeated: nothing to ask
    assert view.map_wanted() is None and view.world_document()["version"] == 2
    view.on_world(world(obstacles=(WALL,), names=("wall",)))  # a new arena: ask again
    assert view.map_wanted() == 2 and view.map_png is None
    assert view.world_document()["map"] is None
    view.on_map(1, picture)  # a late answer about the old arena is ignored
    assert view.map_png is None and view.map_wanted() == 2
    view.on_map(2, None)  # answered: no map
    assert view.map_wanted() is None and view.world_document()["map"] is None


def test_the_console_serves_the_map_picture() -> None:
    view = SwarmView("s")
    picture = lab_picture()
    ((status_code, _),) = asyncio.run(
        _ask(Console(StillFeed(view, picture), None, token=None), ("GET", "/api/map.png", None))
    )
    assert status_code == 404  # no arena: nothing asked, no picture

    async def serve() -> tuple[int, str, bytes, dict]:
        view.on_world(world())
        feed = StillFeed(view, picture)
        console = Console(feed, None, token=None, rate=50.0)
        async with TestClient(TestServer(console.app, host="127.0.0.1")) as client:
            headers = {"Host": "127.0.0.1"}
            for _ in range(100):  # the pump asks within a few periods
                if view.map_png is not None:
                    break
                await asyncio.sleep(0.02)
            response = await client.get("/api/map.png?v=2", headers=headers)
            document = await (await client.get("/api/world", headers=headers)).json()
            for _ in range(5):
                await asyncio.sleep(0.05)
            assert feed.map_queries == 1  # once per arena
            return response.status, response.content_type, await response.read(), document

    code, kind, body, document = asyncio.run(serve())
    assert (code, kind, body) == (200, "image/png", picture.png)
    assert document["map"]["width"] == 200 and document["version"] == 2
    secret = Console(StillFeed(view, picture), None, token="secret-token")
    ((code, _),) = asyncio.run(_ask(secret, ("GET", "/api/map.png", None)))
    assert code == 403  # the token, like every route
