"""What the console believes and whom it serves, without a network (docs/security.md,
docs/steering.md): a pose counts for the robot of the key it came on, and a secured console
wants its token on loopback too."""

from __future__ import annotations

import asyncio
import os
from collections import deque
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from covswarm.console.access import needs_token, read_token_file, refusal
from covswarm.console.model import SwarmView
from covswarm.console.server import Console, SwarmFeed
from covswarm.protocol import Pose, pose_key

SWARM = "s"


class _Sample:
    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr, self.kind = key, None
        self.payload = type("Payload", (), {"to_bytes": lambda _self: payload})()


class _Subscriber:
    def __init__(self) -> None:
        self.queue: deque[_Sample] = deque()

    def try_recv(self) -> _Sample | None:
        return self.queue.popleft() if self.queue else None


class FakeSession:
    """What SwarmFeed declares on a zenoh session, as queues the test fills."""

    def __init__(self) -> None:
        self.subscribers: dict[str, _Subscriber] = {}

    def declare_subscriber(self, key: str, handler: Any, **_: Any) -> _Subscriber:
        return self.subscribers.setdefault(key, _Subscriber())

    def liveliness(self) -> FakeSession:
        return self

    def put(self, key: str, payload: bytes) -> None:
        for selector, subscriber in self.subscribers.items():
            if selector.endswith("/robot/*/pose") and key.endswith("/pose"):
                subscriber.queue.append(_Sample(key, payload))


def pose(robot: int, x: float) -> bytes:
    return Pose(id=robot, x=x, y=0.0, theta=0.0, stamp=1.7e9, seq=1).encode()


def test_a_pose_counts_for_the_robot_of_its_key_only() -> None:
    """Robot 9's certificate lets it put on robot/9/pose only, never inside robot 0's
    messages: a pose saying id 0 on robot 9's key (or on a key of no robot id) is dropped
    and counted as wrong_id; robot 0 is where its own key says."""
    session, view = FakeSession(), SwarmView(SWARM)
    feed = SwarmFeed(session, SWARM, view)
    session.put(pose_key(SWARM, 0), pose(0, 1.0))
    session.put(pose_key(SWARM, 9), pose(0, 2.5))  # robot 9 says it is robot 0
    session.put(f"covswarm/{SWARM}/robot/x/pose", pose(0, 3.0))  # no id in the key
    feed.drain(now=0.0)
    robots = {r["id"]: r["x"] for r in view.snapshot(now=0.0, wall=1.7e9)["robots"]}
    assert robots == {0: 1.0}
    assert view.dropped == {"wrong_id": 2}
    session.put(pose_key(SWARM, 9), pose(9, 2.5))  # its own pose is welcome
    feed.drain(now=0.1)
    robots = {r["id"]: r["x"] for r in view.snapshot(now=0.1, wall=1.7e9)["robots"]}
    assert robots == {0: 1.0, 9: 2.5}


def test_a_secured_console_wants_its_token_on_loopback_too() -> None:
    for host in ("127.0.0.1", "localhost", "::1", "[::1]"):
        assert not needs_token(host)  # open mode: like any local tool
        assert needs_token(host, secure=True)
    assert needs_token("0.0.0.0") and needs_token("127.0.0.2", secure=False)
    loopback = {"Host": "127.0.0.1:7480", "Content-Type": "application/json"}
    refused = refusal(
        expected_token="t" * 32, query={}, headers=loopback, cookies={}, state_changing=True
    )
    assert refused is not None and refused[0] == 403 and "token" in refused[1]
    with_it = {**loopback, "Authorization": "token " + "t" * 32}
    assert refusal(
        expected_token="t" * 32, query={}, headers=with_it, cookies={}, state_changing=True
    ) is None  # fmt: skip


class StillFeed:
    def __init__(self) -> None:
        self.view = SwarmView(SWARM)

    def drain(self, now: float) -> None:
        pass

    def fetch_map(self) -> tuple[bool, Any, str | None]:
        return True, None, None


def test_an_untokened_steer_never_reaches_the_coordinator() -> None:
    asked = []

    async def ask(headers: dict[str, str]) -> int:
        console = Console(StillFeed(), asked.append, token="t" * 32)
        async with TestClient(TestServer(console.app, host="127.0.0.1")) as client:
            response = await client.post(
                "/api/steer",
                data=b'{"kind": "translate", "dx": 1, "dy": 0}',
                headers={"Content-Type": "application/json", "Host": "127.0.0.1", **headers},
            )
            return response.status

    assert asyncio.run(ask({})) == 403
    assert asyncio.run(ask({"Authorization": "token " + "x" * 32})) == 403
    assert asked == []


def test_a_token_file_must_be_the_owners_alone(tmp_path: Path) -> None:
    path = tmp_path / "console.token"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o600)
    os.write(fd, b"abc_DEF-123\n")
    os.close(fd)
    assert read_token_file(str(path)) == "abc_DEF-123"
    path.chmod(0o644)
    with pytest.raises(ValueError, match="readable by others"):
        read_token_file(str(path))
    path.chmod(0o600)
    path.write_text("\n")
    with pytest.raises(ValueError, match="holds no token"):
        read_token_file(str(path))
    with pytest.raises(ValueError, match="cannot read"):
        read_token_file(str(tmp_path / "missing"))
