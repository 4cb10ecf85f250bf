"""The console's sans-IO parts: state model, access rules, the page's steering input.

Cells and per-robot errors are checked against shapely (an independent Voronoi clip), not
against the library that computes them.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from shapely.geometry import MultiPoint, Polygon
from shapely.ops import voronoi_diagram

from covswarm.console.access import (
    COOKIE,
    check_host,
    host_ok,
    needs_token,
    new_token,
    origin_ok,
    presented_token,
    refusal,
    token_ok,
)
from covswarm.console.model import SwarmView
from covswarm.console.steer_input import MAX_BODY, BadSteerInput, parse_steer_body
from covswarm.protocol import Domain, Pose, Status
from covswarm.protocol.steering import SteerRequest

SQUARE = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))


def domain(vertices=SQUARE, t: float = 3.0, state: str = "running", seq: int = 0) -> Domain:
    return Domain(
        seq=seq,
        stamp=1.7e9,
        t=t,
        state=state,
        vertices=vertices,
        velocities=[(0.0, 0.0)] * len(vertices),
        kappa=2.0,
    )


def status(t: float, error: float | None, state: str = "running") -> Status:
    return Status(stamp=1.7e9, t=t, state=state, error=error, alive_agents=3, alive_robots=3)


def pose(ident: int, x: float, y: float, theta: float = 0.0) -> Pose:
    return Pose(id=ident, x=x, y=y, theta=theta, stamp=1.7e9, seq=0)


def shapely_cells(points: np.ndarray, polygon) -> list[Polygon]:
    """Voronoi cells of ``points`` clipped to ``polygon``, in the order of ``points``."""
    region = Polygon(polygon)
    diagram = voronoi_diagram(MultiPoint([tuple(p) for p in points]), envelope=region.buffer(10))
    out = []
    for p in points:
        cell = next(g for g in diagram.geoms if g.buffer(1e-9).contains(MultiPoint([tuple(p)])))
        out.append(cell.intersection(region))
    return out


def test_snapshot_cells_and_errors_match_shapely() -> None:
    rng = np.random.default_rng(7)
    view = SwarmView("s")
    points = rng.uniform(-0.9, 0.9, size=(12, 2))
    for i, (x, y) in enumerate(points):
        view.on_pose(pose(i, x, y, theta=4.0), now=10.0)
    view.on_domain(domain())
    snap = view.snapshot(now=10.5, wall=1.7e9)
    assert [r["id"] for r in snap["robots"]] == list(range(12))
    reference = shapely_cells(points, SQUARE)
    for robot, cell, p in zip(snap["robots"], reference, points, strict=True):
        ours = Polygon(robot["cell"])
        assert ours.hausdorff_distance(cell) < 1e-4  # the JSON rounds to 0.1 mm
        c = np.array(cell.centroid.coords[0])
        assert robot["error"] == pytest.approx(np.linalg.norm(p - c), abs=2e-4)
        # Headings are wrapped into (-pi, pi] for the page.
        assert robot["theta"] == pytest.approx(4.0 - 2 * math.pi, abs=1e-4)
    json.dumps(snap)  # JSON-ready


def test_stale_and_dead_robots_are_not_drawn() -> None:
    view = SwarmView("s", pose_timeout=2.0)
    view.on_domain(domain())
    view.on_pose(pose(0, 0.1, 0.1), now=0.0)
    view.on_pose(pose(1, -0.5, 0.2), now=1.5)
    view.on_pose(pose(2, 0.5, -0.2), now=1.5)
    view.on_liveliness("robot", 2, True)
    view.on_liveliness("robot", 2, False)  # robot 2's process died
    snap = view.snapshot(now=2.5, wall=1.7e9)
    assert [r["id"] for r in snap["robots"]] == [1]  # 0 is 2.5 s old, 2 is gone


def test_error_history_keeps_the_last_minute_and_resets_on_a_new_mission() -> None:
    view = SwarmView("s", error_window=60.0)
    view.on_status(status(0.0, None, state="waiting"))
    for k in range(200):  # 2 Hz for 100 s
        view.on_status(status(0.5 * k, 0.1 + 0.001 * k))
    history = view.snapshot(now=0.0, wall=1.7e9)["error_history"]
    assert history[-1] == [99.5, pytest.approx(0.299)]
    assert history[0][0] == pytest.approx(39.5)
    assert all(b[0] > a[0] for a, b in zip(history, history[1:], strict=False))
    view.on_status(status(1.0, 0.5))  # mission time went back: a restarted mission
    assert view.snapshot(now=0.0, wall=1.7e9)["error_history"] == [[1.0, 0.5]]


def test_snapshot_shape_before_and_after_the_coordinator_speaks() -> None:
    view = SwarmView("s")
    view.on_pose(pose(4, 0.0, 0.0), now=0.0)
    empty = view.snapshot(now=0.1, wall=1.7e9)
    assert empty["t"] is None and empty["state"] == "unknown" and empty["polygon"] == []
    assert empty["robots"] == [
        {"id": 4, "x": 0.0, "y": 0.0, "theta": 0.0, "error": None, "cell": None}
    ]
    view.on_domain(domain(t=12.25))
    view.on_status(status(12.0, 0.02))
    for role, ident in (("agent", 4), ("robot", 4), ("coordinator", 0)):
        view.on_liveliness(role, ident, True)
    snap = view.snapshot(now=0.2, wall=1.7e9)
    assert snap["t"] == 12.25 and snap["state"] == "running"
    assert snap["polygon"] == [list(v) for v in SQUARE]
    assert snap["error"] == 0.02
    assert snap["alive"] == {"agents": 1, "robots": 1, "coordinator": True}
    assert snap["robots"][0]["cell"] is not None


def test_an_unusable_polygon_is_counted_and_draws_no_cells() -> None:
    view = SwarmView("s")
    bowtie = ((-1.0, -1.0), (1.0, 1.0), (1.0, -1.0), (-1.0, 1.0))
    view.on_domain(domain(vertices=bowtie))
    view.on_pose(pose(0, 0.2, 0.0), now=0.0)
    snap = view.snapshot(now=0.1, wall=1.7e9)
    assert snap["robots"][0]["cell"] is None and snap["robots"][0]["error"] is None
    assert snap["dropped"] == {"geometry": 1}


def test_steering_outcomes_are_kept_for_the_page() -> None:
    view = SwarmView("s")
    for k in range(25):
        view.on_steering({"wall": float(k), "accepted": k % 2 == 0, "reason": ""})
    steering = view.snapshot(now=0.0, wall=1.7e9)["steering"]
    assert len(steering) == 20 and steering[-1]["wall"] == 24.0


# -- access -----------------------------------------------------------------------------------


def test_only_the_default_loopback_address_goes_without_a_token() -> None:
    for host in ("127.0.0.1", "localhost", "::1", "[::1]"):
        assert not needs_token(host)
    for host in ("0.0.0.0", "127.0.0.2", "192.168.1.5", "::", "example.org"):
        assert needs_token(host)


def test_an_empty_address_is_refused_rather_than_every_interface() -> None:
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    for host in ("", " "):
        with pytest.raises(ValueError, match="0.0.0.0 for every interface"):
            check_host(host)
    assert check_host("0.0.0.0") == "0.0.0.0"
    args = ["console", "--connect", "tcp/127.0.0.1:1", "--swarm", "s", "--host", ""]
    done = CliRunner().invoke(main, args)
    assert done.exit_code == 2 and "an empty address" in done.output, done.output


def test_token_check() -> None:
    token = new_token()
    assert len(token) >= 32 and token != new_token()
    assert token_ok(None, None)
    assert token_ok(token, token)
    assert not token_ok(token, None)
    assert not token_ok(token, token[:-1])
    assert not token_ok(token, token + "x")
    assert not token_ok(token, "")


def test_the_token_may_come_in_the_url_a_header_or_the_cookie() -> None:
    assert presented_token({"token": "a"}, {}, {}) == "a"
    assert presented_token({}, {"Authorization": "token b"}, {}) == "b"
    assert presented_token({}, {"Authorization": "Bearer c"}, {}) == "c"
    assert presented_token({}, {}, {COOKIE: "d"}) == "d"
    assert presented_token({}, {"Authorization": "Basic e"}, {}) is None
    assert presented_token({}, {}, {}) is None


def test_host_and_origin_rules() -> None:
    assert host_ok("127.0.0.1:7480", token_required=False)
    assert host_ok("localhost:7480", token_required=False)
    assert host_ok("[::1]:7480", token_required=False)
    assert not host_ok("evil.example:7480", token_required=False)  # DNS rebinding
    assert not host_ok(None, token_required=False)
    assert host_ok("evil.example:7480", token_required=True)
    assert origin_ok(None, "127.0.0.1:7480")  # scripts send no Origin
    assert origin_ok("http://127.0.0.1:7480", "127.0.0.1:7480")
    assert not origin_ok("http://evil.example", "127.0.0.1:7480")
    assert not origin_ok("http://127.0.0.1:9999", "127.0.0.1:7480")
    assert not origin_ok("null", "127.0.0.1:7480")


def test_refusal_applies_every_rule() -> None:
    token = new_token()
    host = {"Host": "10.0.0.2:7480"}

    def check(expected, query=None, headers=None, cookies=None, state_changing=False):
        return refusal(
            expected_token=expected,
            query=query or {},
            headers=headers or {},
            cookies=cookies or {},
            state_changing=state_changing,
        )

    assert check(token, headers=host)[0] == 403
    assert check(token, query={"token": "wrong"}, headers=host)[0] == 403
    assert check(token, query={"token": token}, headers=host) is None
    assert check(token, cookies={COOKIE: token}, headers=host) is None
    evil = {**host, "Origin": "http://evil.example"}
    assert check(token, cookies={COOKIE: token}, headers=evil) is None  # a plain GET
    assert check(token, cookies={COOKIE: token}, headers=evil, state_changing=True)[0] == 403
    assert check(None, headers={"Host": "127.0.0.1:7480"}) is None
    assert check(None, headers={"Host": "rebound.example:7480"})[0] == 403


# -- the page's steering requests --------------------------------------------------------------


def body(obj) -> bytes:
    return json.dumps(obj).encode()


def test_page_requests_become_steer_requests() -> None:
    assert parse_steer_body(body({"kind": "translate", "dx": 0.5, "dy": -1})) == SteerRequest(
        "translate", dx=0.5, dy=-1.0
    )
    rotate = parse_steer_body(body({"kind": "rotate", "angle": 0.3, "about": [1, 2]}))
    assert rotate.angle == 0.3 and rotate.about == (1.0, 2.0)
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    assert parse_steer_body(body({"kind": "polygon", "polygon": square})).polygon == tuple(
        (float(x), float(y)) for x, y in square
    )
    scale = parse_steer_body(body({"kind": "scale", "factor": 2, "duration": 3}))
    assert scale.factor == 2.0 and scale.duration == 3.0


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        (b"{", "not JSON"),
        (b"\xff\xfe", "not JSON"),
        (b'{"kind": "translate", "dx": NaN, "dy": 0}', "NaN"),
        (b'{"kind": "translate", "dx": Infinity, "dy": 0}', "Infinity"),
        (body([1, 2]), "JSON object"),
        (body({"dx": 1}), "kind"),
        (body({"kind": "teleport"}), "kind"),
        (body({"kind": "translate", "dx": 1, "extra": 2}), "unknown fields"),
        (body({"kind": "translate", "dx": "1"}), "number"),
        (body({"kind": "translate", "dx": True}), "number"),
        (body({"kind": "translate", "dx": 1e9}), "outside"),
        (body({"kind": "scale", "factor": -2}), "factor"),
        (body({"kind": "translate", "dx": 1, "angle": 1}), "does not use"),
        (body({"kind": "polygon"}), "polygon"),
        (body({"kind": "polygon", "polygon": [[0, 0], [1, 0]]}), "points"),
        (body({"kind": "translate", "dx": 1, "duration": 2, "speed": 1}), "not both"),
        (b" " * (MAX_BODY + 1), "limit"),
    ],
)
def test_malformed_page_requests_are_refused_with_the_reason(raw: bytes, words: str) -> None:
    with pytest.raises(BadSteerInput, match=words):
        parse_steer_body(raw)


def test_snapshot_carries_the_density_the_page_shades() -> None:
    """The page evaluates floor + sum w exp(-1/2 u^T P u) from the snapshot: that must be
    the broadcast density's phi (independently: its covariances inverted by numpy)."""
    from covswarm.tvd.density import Density

    bumps = Density(floor=1.0, means=[[0.2, -0.3], [-0.5, 0.4]],
                    covariances=[[[0.09, 0.03], [0.03, 0.04]], [[0.25, 0.0], [0.0, 0.01]]],
                    weights=[6.0, 2.5])  # fmt: skip
    view = SwarmView("s")
    broadcast = Domain(seq=0, stamp=1.7e9, t=3.0, state="running", vertices=SQUARE,
                       velocities=[(0.0, 0.0)] * 4, kappa=2.0, density=bumps.to_dict())  # fmt: skip
    view.on_domain(broadcast)
    shown = view.snapshot(now=10.0, wall=1.7e9)["density"]
    json.dumps(shown)
    q = np.random.default_rng(5).uniform(-1.0, 1.0, (200, 2))
    phi = np.full(len(q), shown["floor"])
    for bump, cov in zip(shown["bumps"], bumps.covariances, strict=True):
        np.testing.assert_allclose(bump["precision"], np.linalg.inv(cov), atol=1e-4)
        u = q - bump["mean"]
        phi += bump["weight"] * np.exp(-0.5 * np.einsum("ni,ij,nj->n", u, bump["precision"], u))
    np.testing.assert_allclose(phi, bumps.phi(q), rtol=1e-4)
    view.on_domain(domain())  # uniform: nothing to shade
    assert view.snapshot(now=10.0, wall=1.7e9)["density"] is None
