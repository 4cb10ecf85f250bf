"""The console answers every unreadable steering body with 400 (issue 21, item 4), never
500 and never a traceback, and logs refused requests rate-limited. aiohttp's test server
on loopback; the Zenoh feed is replaced by a bare SwarmView (no subscription is needed to
refuse a body)."""

from __future__ import annotations

import asyncio
import json
import logging
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from covswarm.console.model import SwarmView
from covswarm.console.server import Console
from covswarm.console.steer_input import MAX_BODY, BadSteerInput, parse_steer_body


class StillFeed:
    """A feed that hears nothing: the console's view stays empty."""

    def __init__(self) -> None:
        self.view = SwarmView("test")

    def drain(self, now: float) -> None:
        pass


def never_steer(request: Any) -> Any:
    raise AssertionError(f"an unreadable body reached the coordinator: {request}")


UNREADABLE = {
    "deeply nested": b"[" * 16_000 + b"]" * 16_000,
    "nested objects": b'{"a":' * 5_000 + b"1" + b"}" * 5_000,
    "nested past the size limit": b"[" * 100_000 + b"]" * 100_000,
    "5000 digits": b'{"kind": "translate", "dx": ' + b"7" * 5000 + b"}",
    "5000 digits alone": b"9" * 5000,
    "invalid UTF-8": b'{"kind": "translate", "dx": "\xff\xfe"}',
    "lone surrogate": b'{"kind": "translate\\ud800"}',
    "a list": b"[1, 2, 3]",
    "a string": b'"translate"',
    "null": b"null",
    "a number": b"1e999",
    "empty": b"",
    "truncated": b'{"kind": "transl',
    "nested field": b'{"kind": "polygon", "polygon": ' + b"[" * 5000 + b"]" * 5000 + b"}",
    "object as polygon": b'{"kind": "polygon", "polygon": {"a": 1}}',
    "huge float": b'{"kind": "translate", "dx": 1e999}',
}


# Bodies larger than the console reads never reach the parser (413, tested below).
@pytest.mark.parametrize("name", sorted(n for n, b in UNREADABLE.items() if len(b) <= MAX_BODY))
def test_parse_refuses_with_a_sentence(name: str) -> None:
    body = UNREADABLE[name]
    with pytest.raises(BadSteerInput):
        parse_steer_body(body)


async def _post_all(bodies: dict[str, bytes]) -> dict[str, tuple[int, str]]:
    console = Console(StillFeed(), never_steer, token=None)
    answers = {}
    async with TestClient(TestServer(console.app, host="127.0.0.1")) as client:
        for name, body in bodies.items():
            response = await client.post(
                "/api/steer",
                data=body,
                headers={"Content-Type": "application/json", "Host": "127.0.0.1"},
            )
            answers[name] = (response.status, await response.text())
    return answers


def test_every_unreadable_body_gets_400_without_a_traceback(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.WARNING, logger="covswarm.console"):
        answers = asyncio.run(_post_all(UNREADABLE))
    for name, (status, text) in answers.items():
        too_big = len(UNREADABLE[name]) > MAX_BODY
        assert status == (413 if too_big else 400), (name, status, text[:300])
        assert "Traceback" not in text and 'File "' not in text, name
        if not too_big:
            answer = json.loads(text)
            assert answer["accepted"] is False and answer["reason"].startswith("malformed")


def test_a_flood_of_refused_posts_logs_a_few_lines(caplog: pytest.LogCaptureFixture) -> None:
    bodies = {f"bad {k}": b"[1]" for k in range(300)}
    with caplog.at_level(logging.WARNING, logger="covswarm.console"):
        answers = asyncio.run(_post_all(bodies))
    assert {status for status, _ in answers.values()} == {400}
    refused = [r for r in caplog.records if "steering refused" in r.getMessage()]
    assert 1 <= len(refused) <= 3


async def _first_frames(count: int) -> list[str]:
    console = Console(StillFeed(), never_steer, token=None)
    async with TestClient(TestServer(console.app, host="127.0.0.1")) as client:
        ws = await client.ws_connect("/ws", headers={"Host": "127.0.0.1"})
        frames = [await asyncio.wait_for(ws.receive_str(), 10.0) for _ in range(count)]
        await ws.close()
    return frames


def test_a_fresh_consoles_first_page_gets_state_documents_only() -> None:
    # Its first frame was the empty text of a state not built yet: the page's JSON.parse threw.
    for frame in asyncio.run(_first_frames(3)):
        assert json.loads(frame)["swarm"] == "test"


def test_a_console_that_hears_no_domain_says_so_once(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A wrong --swarm (or no coordinator yet): the page only shows "unknown".
    from covswarm.console import server

    monkeypatch.setattr(server, "SILENT_AFTER", 0.3)

    async def run() -> None:
        console = Console(StillFeed(), never_steer, token=None, rate=20.0)
        async with TestClient(TestServer(console.app, host="127.0.0.1")):
            await asyncio.sleep(1.0)

    with caplog.at_level(logging.WARNING, logger="covswarm.console"):
        asyncio.run(run())
    silent = [r for r in caplog.records if "no domain of swarm 'test'" in r.getMessage()]
    assert len(silent) == 1
