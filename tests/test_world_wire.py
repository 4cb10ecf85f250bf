"""The World message (protocol.World) and its conversion (covswarm.world.wire): exact round
trips, strict decoding with a reason, outward rounding checked with shapely, sizes, fuzz."""

from __future__ import annotations

import math
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from script_modules import load_script

from covswarm import protocol
from covswarm.protocol.messages import MAX_OBSTACLES, MAX_WORLD_PAYLOAD, World
from covswarm.tvd.geometry import validate_convex
from covswarm.world.maps import world_from_map
from covswarm.world.model import Obstacle
from covswarm.world.model import World as Arena
from covswarm.world.wire import from_message, outward_mm, to_message

ROOT = Path(__file__).resolve().parents[1]
STAMP = 1.7e9
SQUARE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))
TRIANGLE = ((2.0, 2.0), (3.0, 2.0), (2.5, 3.0))


def pack(wire: dict) -> bytes:
    return msgpack.packb({"v": 1, **wire}, use_bin_type=True)


def refusal(payload: bytes) -> str:
    with pytest.raises(protocol.ProtocolError) as info:
        World.decode(payload)
    assert info.value.reason in protocol.REASONS
    return str(info.value)


def test_key() -> None:
    assert protocol.world_key("s1") == "covswarm/s1/world"
    with pytest.raises(ValueError):
        protocol.world_key("a/b")


def test_round_trip_boxes_polygons_names() -> None:
    message = World(
        seq=3,
        stamp=STAMP,
        obstacles=(SQUARE, TRIANGLE, ((-1.2345, 0.5), (-1.0, 0.25), (-0.8, 0.9))),
        workspace=(-5.0, 5.0, -3.0, 3.0),
        names=("shelf", "map piece 7", "map piece 8"),
    )
    assert World.decode(message.encode()) == message
    raw = msgpack.unpackb(message.encode())
    assert raw["obstacles"][0] == [0, 0, 1000, 1000]  # a box: x, y, w, h in mm
    assert raw["obstacles"][1] == [2000, 2000, 1000, 0, -500, 1000]  # then deltas
    assert raw["names"] == ["shelf", ["map piece", 7, 2]]
    assert raw["workspace"] == [-5000, 5000, -3000, 3000]


def test_default_names_are_left_out() -> None:
    message = World(seq=0, stamp=STAMP, obstacles=(SQUARE, TRIANGLE))
    assert message.names == ("obstacle 1", "obstacle 2")
    raw = msgpack.unpackb(message.encode())
    assert set(raw) == {"v", "seq", "stamp", "obstacles"}
    assert World.decode(message.encode()) == message
    empty = World(seq=0, stamp=STAMP, obstacles=())
    assert World.decode(empty.encode()) == empty and empty.workspace is None


def test_names_that_look_numbered_round_trip() -> None:
    names = ("a 1", "a 2", "a  3", "a 04", "b 9", "b 10", "x", "a 3", "c 999999999", "c 1000000000")
    message = World(seq=0, stamp=STAMP, obstacles=(SQUARE,) * len(names), names=names)
    assert World.decode(message.encode()).names == names


@pytest.mark.parametrize(
    ("wire", "why"),
    [
        ({"seq": 1, "stamp": STAMP}, "missing"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [], "extra": 1}, "unknown"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 0, 5]]}, "w, h > 0"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 5]]}, "expected a box"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 1.5, 1, 1, 1]]}, "expected an int"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, True, 1, 1, 1]]}, "expected an int"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 0, 10, 10, 0]]}, "clockwise"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 5, 0, 5, 0, -5, 5]]}, "straight"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 0, 0, 10, 0, 0, 10]]}, "repeated"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 10, 5, -10, 0, 0, 10]]}, "clockwise"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[10**8, 0, 1, 1]]}, "outside"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 1, 1]], "names": ["a", "b"]}, "names"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 1, 1]], "names": [["a", 1, 2]]}, "count"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 1, 1]], "names": [""]}, "name of"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [[0, 0, 1, 1]], "names": [["a", 0, 1]]}, "first"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [], "workspace": [0, 0, 1, 2]}, "xmin < xmax"),
        ({"seq": 1, "stamp": STAMP, "obstacles": [], "workspace": [0, 1.0, 1, 2]}, "an int"),
        ({"seq": -1, "stamp": STAMP, "obstacles": []}, "seq"),
        ({"seq": 1, "stamp": math.nan, "obstacles": []}, "stamp"),
    ],
)
def test_strict_decode(wire: dict, why: str) -> None:
    assert why in refusal(pack(wire))


def test_star_is_refused() -> None:
    # Every corner turns left, yet the outline winds twice: a pentagram.
    angles = np.arange(5) * 4 * np.pi / 5
    star = np.round(1000 * np.stack([np.cos(angles), np.sin(angles)], axis=1)).astype(int)
    flat = [int(star[0, 0]), int(star[0, 1])]
    for a, b in zip(star, star[1:], strict=False):
        flat += [int(b[0] - a[0]), int(b[1] - a[1])]
    assert "winds more than once" in refusal(pack({"seq": 1, "stamp": STAMP, "obstacles": [flat]}))


def test_version_and_size_bounds() -> None:
    assert "version" in refusal(msgpack.packb({"v": 2, "seq": 1, "stamp": STAMP, "obstacles": []}))
    assert "limit" in refusal(b"\x00" * (MAX_WORLD_PAYLOAD + 1))
    many = [[0, 0, 1, 1]] * (MAX_OBSTACLES + 1)
    assert "at most" in refusal(pack({"seq": 1, "stamp": STAMP, "obstacles": many}))
    with pytest.raises(protocol.ProtocolError, match="65 points"):
        World(seq=0, stamp=STAMP, obstacles=(tuple((math.cos(a), math.sin(a)) for a in range(65)),))


def test_convexity_agrees_with_validate_convex() -> None:
    """The wire's integer test against tvd.geometry.validate_convex on random point lists:
    accepted exactly when validate_convex keeps every vertex, in order, counter-clockwise."""
    rng = np.random.default_rng(7)
    seen = {True: 0, False: 0}
    for _ in range(2000):
        k = int(rng.integers(3, 8))
        points = rng.integers(-50, 50, size=(k, 2)) / 1000.0
        if rng.random() < 0.5:  # convex ones too: a hull in CCW order
            points = np.array(shapely.MultiPoint(points).convex_hull.exterior.coords)[:-1]
            if len(points) < 3:
                continue
            points = points[::-1] if shapely.Polygon(points).exterior.is_ccw is False else points
        polygon = tuple(map(tuple, points))
        try:
            World(seq=0, stamp=STAMP, obstacles=(polygon,))
            accepted = True
        except protocol.ProtocolError:
            accepted = False
        try:
            kept = validate_convex(points)
            reference = len(kept) == len(points) and shapely.Polygon(points).exterior.is_ccw
        except ValueError:
            reference = False
        assert accepted == reference, points
        seen[accepted] += 1
    assert min(seen.values()) > 200


def test_to_message_rounds_outward_and_inward() -> None:
    """Obstacles grow (the sent polygon contains the true one, by at most a grid diagonal),
    the workspace shrinks; shapely is the reference."""
    rng = np.random.default_rng(11)
    for _ in range(300):
        k = int(rng.integers(3, 12))
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        radius = rng.uniform(0.002, 3.0)
        centre = rng.uniform(-50, 50, 2)
        vertices = centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        try:
            obstacle = Obstacle("o", vertices)
        except ValueError:
            continue
        arena = Arena((-60.0004, 60.0004, -60.0006, 60.9999), (obstacle,))
        message = to_message(arena, 1, STAMP)
        sent = shapely.Polygon(message.obstacles[0])
        true = shapely.Polygon(obstacle.vertices)
        assert sent.buffer(1e-9).contains(true)
        assert sent.hausdorff_distance(true) <= math.sqrt(2) * 1e-3 + 1e-9
        assert message.workspace == (-60.0, 60.0, -60.0, 60.999)
    exact = Arena((-5.0, 5.0, -3.0, 3.0), (Obstacle("a", np.array(SQUARE) * 0.05),))
    assert to_message(exact, 1, STAMP).obstacles[0] == tuple(
        (x * 0.05, y * 0.05) for x, y in SQUARE
    )
    assert outward_mm(np.array([[0.0, 0.0], [0.0004, 0.0], [0.0, 0.0004]])) == [
        (0, 0),
        (1, 0),
        (0, 1),
    ]


def test_lab_map_round_trips_and_is_small() -> None:
    arena = world_from_map(ROOT / "scenarios" / "lab.yaml")
    payload = to_message(arena, 5, STAMP).encode()
    assert len(payload) < 300  # 217 bytes (docs/world.md)
    back = from_message(World.decode(payload))
    assert back.workspace == arena.workspace
    assert [o.name for o in back.obstacles] == [o.name for o in arena.obstacles]
    for a, b in zip(arena.obstacles, back.obstacles, strict=True):
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-12)


def test_twenty_metre_map_is_small(tmp_path: Path) -> None:
    sizes = load_script("world_size").sizes(tmp_path)
    count, size = sizes["20 m x 20 m at 5 cm"]
    assert count >= 30 and size < 1024  # 508 bytes (docs/world.md)
    arena = world_from_map(tmp_path / "warehouse20.yaml")
    back = from_message(World.decode(to_message(arena, 1, time.time()).encode()))
    assert len(back.obstacles) == count


# --- fuzz -------------------------------------------------------------------------------

FUZZ = settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)
ints = st.one_of(
    st.integers(-2000, 2000),
    st.sampled_from([0, -1, 10**7, -(10**7), 10**7 + 1, 2**31, -(2**63), 2**64 - 1]),
)
junk = st.sampled_from([None, True, "x", 1.5, math.nan, [], {}, [1, 2], b"\x00"])
obstacles = st.lists(st.one_of(st.lists(ints, min_size=0, max_size=12), junk), max_size=6)
names = st.one_of(
    st.lists(
        st.one_of(st.text(max_size=70), st.tuples(st.text(max_size=5), ints, ints)), max_size=8
    ),
    junk,
)


@FUZZ
@given(
    st.fixed_dictionaries(
        {
            "v": st.one_of(st.just(1), junk),
            "seq": st.one_of(ints, junk),
            "stamp": st.one_of(st.floats(0, 2e9), junk),
            "obstacles": st.one_of(obstacles, junk),
        },
        optional={
            "workspace": st.one_of(st.lists(ints, max_size=5), junk),
            "names": names,
            "x": junk,
        },
    )
)
def test_world_decode_accepts_or_gives_a_reason(wire: dict) -> None:
    payload = msgpack.packb(wire, use_bin_type=True)
    try:
        message = World.decode(payload)
    except protocol.ProtocolError as exc:
        assert exc.reason in protocol.REASONS and str(exc)
        return
    assert World.decode(message.encode()) == message
    arena = from_message(message)  # a decoded World is a valid model World
    assert len(arena.obstacles) == len(message.obstacles)


@FUZZ
@given(st.binary(max_size=200))
def test_world_decode_random_bytes(payload: bytes) -> None:
    try:
        World.decode(payload)
    except protocol.ProtocolError as exc:
        assert exc.reason in protocol.REASONS
