"""A known limit of the Foxglove live view (docs/records.md, docs/security.md): foxglove-sdk
0.30's WebSocket server checks no ``Origin`` and offers no hook to (its ServerListener hears
of a client only by a number, after the handshake), so a web page of any site open in the
operator's browser can connect to ws://127.0.0.1:PORT and read the run."""

from __future__ import annotations

import asyncio

from covswarm.records.recorder import RunRecorder


def test_a_cross_site_origin_is_not_refused_by_foxglove_sdk() -> None:
    """If a later foxglove-sdk refuses a foreign Origin (or lets us), this fails: refuse
    every Origin but loopback's and the Foxglove app's, and say so in the docs."""
    import websockets

    recorder = RunRecorder(None, run_metadata={"scenario": "unit"}, live_port=0)
    url = f"ws://127.0.0.1:{recorder.live_port}"

    async def handshake(origin: str | None) -> str:
        try:
            async with websockets.connect(
                url, subprotocols=["foxglove.sdk.v1"], origin=origin
            ) as ws:
                return f"open {ws.subprotocol}"
        except websockets.InvalidStatus as exc:
            return f"HTTP {exc.response.status_code}"

    try:
        assert asyncio.run(handshake(None)) == "open foxglove.sdk.v1"
        assert asyncio.run(handshake("http://evil.example")) == "open foxglove.sdk.v1"
    finally:
        recorder.close()
