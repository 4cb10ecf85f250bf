"""``covswarm console``: the operator's web page for a running swarm, served by aiohttp.

A thin shell: :class:`SwarmFeed` subscribes to the swarm's domain, status, world, poses and
liveliness tokens (keys of covswarm.protocol) and feeds a console.model.SwarmView; the
web app serves the page (console/static, shipped in the package: no CDN), pushes the state
document over a WebSocket at ``--rate`` Hz, answers ``GET /api/state`` with the same
document, answers ``GET /api/world`` with the arena (workspace and obstacles, fetched by the
page when the state's world version changes) and forwards the page's steering requests
(``POST /api/steer``, checked by console.steer_input) to the coordinator with
covswarm.coordinator.steer_client. Every request passes console.access first (token, Host,
Origin).

Routes: ``/`` the page, ``/static/*`` its assets, ``/ws`` the state stream,
``/api/state`` the state as JSON, ``/api/world`` the arena as JSON (404 before the
coordinator has sent one), ``/api/map.png`` the map's picture (protocol.MapImage, asked of
the coordinator once per arena; 404 without one; placed by the arena's ``map`` entry),
``/api/steer`` steering (JSON body, answer ``{accepted, reason,
duration, route}``, route an accepted goto's stops [x m, y m, scale of S] or null).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import signal
import socket
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import click
from aiohttp import web

from covswarm.console.access import (
    COOKIE,
    DEFAULT_HOST,
    check_host,
    needs_token,
    new_token,
    read_token_file,
    refusal,
)
from covswarm.console.model import SwarmView
from covswarm.console.steer_input import MAX_BODY, BadSteerInput, parse_steer_body
from covswarm.protocol.inbound import RateLimit
from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.runtime.options import connect_option, float_option
from covswarm.runtime.ratelog import RateLog

log = logging.getLogger("covswarm.console")

STATIC = Path(__file__).with_name("static")
DEFAULT_PORT = 7480
DEFAULT_RATE = 15.0  # Hz of state frames to the page (>= 10 for smooth motion)
STATE_PATHS = ("/ws", "/api/steer")  # requests that can steer or stream: Origin checked
MAP_TIMEOUT = 3.0  # s a query for the map's picture waits for the coordinator
MAP_RETRY = 5.0  # s before asking again when no coordinator answered
SILENT_AFTER = 10.0  # s without a domain before the console says it hears no coordinator


class SwarmFeed:
    """The console's Zenoh subscriptions, drained into a SwarmView (no threads of its own)."""

    def __init__(self, session: Any, swarm: str, view: SwarmView) -> None:
        import zenoh

        from covswarm.protocol import (
            KeyIds,
            alive_selector,
            all_poses_selector,
            domain_key,
            status_key,
            world_key,
        )

        self.swarm, self.view = swarm, view
        self._session = session
        self._pose_ids = KeyIds(swarm, "pose")  # a pose's robot is its key's
        self._delete = zenoh.SampleKind.DELETE
        # Latest-wins streams in rings (drained every frame); liveliness in a FIFO, since a
        # lost change would leave a dead process counted alive.
        self._domain = session.declare_subscriber(domain_key(swarm), zenoh.handlers.RingChannel(8))
        self._status = session.declare_subscriber(status_key(swarm), zenoh.handlers.RingChannel(8))
        # The coordinator repeats its World every second: a console started late gets it.
        self._world = session.declare_subscriber(world_key(swarm), zenoh.handlers.RingChannel(2))
        self._poses = session.declare_subscriber(
            all_poses_selector(swarm), zenoh.handlers.RingChannel(4096)
        )
        self._alive = session.liveliness().declare_subscriber(
            alive_selector(swarm), zenoh.handlers.FifoChannel(4096), history=True
        )

    def drain(self, now: float) -> None:
        """Feed everything received since the last call to the view (``now``: monotonic s)."""
        from covswarm.protocol import Domain, Pose, ProtocolError, Status, World, parse_alive_key

        view = self.view
        while (sample := self._alive.try_recv()) is not None:
            try:
                role, ident = parse_alive_key(str(sample.key_expr), self.swarm)
            except ValueError:
                view.on_dropped("key")
                continue
            view.on_liveliness(role, ident, sample.kind != self._delete)
        for channel, kind in ((self._domain, Domain), (self._status, Status), (self._world, World)):
            newest = None
            while (sample := channel.try_recv()) is not None:
                newest = sample
            if newest is not None:
                try:
                    message = kind.decode(newest.payload.to_bytes())
                except ProtocolError as exc:
                    view.on_dropped(exc.reason)
                    continue
                if kind is Domain:
                    view.on_domain(message)
                elif kind is Status:
                    view.on_status(message)
                else:
                    view.on_world(message)
        latest: dict[str, bytes] = {}
        while (sample := self._poses.try_recv()) is not None:
            latest[str(sample.key_expr)] = sample.payload.to_bytes()
        for key, payload in latest.items():
            try:
                pose = Pose.decode(payload)
            except ProtocolError as exc:
                view.on_dropped(exc.reason)
                continue
            # The key is what the router checked (in secure mode robot 9 may put only on
            # robot/9/pose), not the id inside: a pose of another id, or on a key of another
            # shape, is dropped (docs/security.md).
            if pose.id != self._pose_ids(key):
                view.on_dropped("wrong_id")
                continue
            view.on_pose(pose, now)

    def fetch_map(self) -> tuple[bool, Any, str | None]:
        """Ask the coordinator for the map's picture (blocking: run it in a worker thread,
        at most MAP_TIMEOUT s). Returns (answered, protocol.MapImage or None, why dropped):
        not answered: nobody replied, ask again later; answered with None: the scenario has
        no map, or the picture did not decode (the ProtocolError's reason, to count)."""
        from covswarm.protocol import MapImage, ProtocolError, world_map_key

        replies = self._session.get(world_map_key(self.swarm), timeout=MAP_TIMEOUT)
        for reply in replies:
            if reply.ok is None:  # the coordinator's "no map"
                return True, None, None
            try:
                return True, MapImage.decode(reply.ok.payload.to_bytes()), None
            except ProtocolError as exc:
                return True, None, exc.reason
        return False, None, None


class Console:
    """The web app around one SwarmFeed: page, state stream, state API, steering."""

    def __init__(
        self,
        feed: SwarmFeed,
        steer: Callable[[Any], Any] | None,
        *,
        token: str | None,
        rate: float = DEFAULT_RATE,
    ) -> None:
        """``steer``: a blocking SteerRequest -> SteerReply (SteeringClient.request), run in
        a worker thread; None refuses every steering request (no coordinator to ask)."""
        self.feed, self.view = feed, feed.view
        self._steer = steer
        self.token = token
        self.period = 1.0 / rate
        self._frame = ""  # latest state document, JSON
        self._frame_at = -float("inf")  # monotonic s it was built
        self._world_json: tuple[int, str] | None = None  # (version, /api/world's JSON)
        self._version = 0
        self._changed = asyncio.Condition()
        self._steer_lock = asyncio.Lock()
        self.clients = 0
        self.refused_requests = 0
        self._refusal_log = RateLimit()
        self._steer_log = RateLog(log)  # refused steering: a flood of POSTs logs a few lines
        self._map_task: asyncio.Task[None] | None = None  # a map query in flight
        self._map_next = 0.0  # monotonic s before which no map query is made
        self._silent_since: float | None = None  # monotonic s the pump started, until heard
        self.app = web.Application(middlewares=[self._guard], client_max_size=MAX_BODY)
        self.app.router.add_get("/", self._index)
        self.app.router.add_get("/ws", self._stream)
        self.app.router.add_get("/api/state", self._state)
        self.app.router.add_get("/api/world", self._world)
        self.app.router.add_get("/api/map.png", self._map)
        self.app.router.add_post("/api/steer", self._steer_request)
        self.app.router.add_static("/static", STATIC, show_index=False, follow_symlinks=False)
        self.app.on_startup.append(self._start_pump)
        self.app.on_cleanup.append(self._stop_pump)

    # -- access -----------------------------------------------------------------------------

    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        refused = refusal(
            expected_token=self.token,
            query=request.query,
            headers=request.headers,
            cookies=request.cookies,
            state_changing=request.path in STATE_PATHS,
        )
        if refused is not None:
            status, reason = refused
            self.refused_requests += 1
            if self._refusal_log.ready():
                log.warning(
                    "refused %s %s from %s: %s (%d refused so far)",
                    request.method,
                    request.path,
                    request.remote,
                    reason,
                    self.refused_requests,
                )
            return web.json_response({"error": reason}, status=status)
        return await handler(request)

    # -- state ------------------------------------------------------------------------------

    def frame(self) -> str:
        """The state document as JSON, rebuilt at most once per period (shared by all)."""
        now = time.monotonic()
        if now - self._frame_at >= 0.5 * self.period:
            self.feed.drain(now)
            document = self.view.snapshot(now, time.time())
            document["console"] = {"pages": self.clients, "refused_requests": self.refused_requests}
            self._frame = json.dumps(document, separators=(",", ":"))
            self._frame_at = now
            self._version += 1
        return self._frame

    async def _pump(self) -> None:
        """Every period: drain the subscriptions, and push a frame if anyone watches."""
        next_at = time.monotonic()
        while True:
            if self.clients:
                self.frame()
                async with self._changed:
                    self._changed.notify_all()
            else:
                self.feed.drain(time.monotonic())
            self._ask_for_map()
            self._warn_if_silent()
            next_at += self.period
            delay = next_at - time.monotonic()
            if delay < -self.period:
                next_at = time.monotonic()  # overloaded: restart the schedule, no burst
            await asyncio.sleep(max(0.0, delay))

    def _warn_if_silent(self) -> None:
        """Log once when no domain of the swarm came within SILENT_AFTER s: the coordinator
        is not up, or --swarm names another swarm (the page only says "unknown")."""
        now = time.monotonic()
        if self._silent_since is None:
            self._silent_since = now
        elif self.view.domain is not None:
            self._silent_since = math.inf
        elif now - self._silent_since >= SILENT_AFTER:
            self._silent_since = math.inf
            log.warning(
                "no domain of swarm %r heard in %.0f s: is its coordinator running, and is "
                '--swarm its name (launch.json\'s "swarm")?',
                self.view.swarm,
                SILENT_AFTER,
            )

    def _ask_for_map(self) -> None:
        """Once per arena (World content), ask the coordinator for its map's picture in a
        worker thread; again after MAP_RETRY s if nobody answered."""
        wanted = self.view.map_wanted()
        if wanted is None or self._map_task is not None or time.monotonic() < self._map_next:
            return

        async def ask() -> None:
            try:
                loop = asyncio.get_running_loop()
                answered, image, dropped = await loop.run_in_executor(None, self.feed.fetch_map)
            except Exception as exc:  # a closed session: the console goes on without a map
                log.warning("cannot ask for the map's picture: %s", exc)
                answered, image, dropped = False, None, None
            finally:
                self._map_task = None
            if dropped is not None:
                self.view.on_dropped(dropped)
            if answered:
                self.view.on_map(wanted, image)
            else:
                self._map_next = time.monotonic() + MAP_RETRY

        self._map_task = asyncio.create_task(ask())

    async def _start_pump(self, app: web.Application) -> None:
        self._pump_task = asyncio.create_task(self._pump())

    async def _stop_pump(self, app: web.Application) -> None:
        self._pump_task.cancel()

    # -- handlers ---------------------------------------------------------------------------

    async def _index(self, request: web.Request) -> web.StreamResponse:
        if "token" in request.query:
            # The token came in the URL (checked by _guard): keep it in a cookie that only
            # this site sends, and drop it from the address bar and the browser history.
            response = web.HTTPFound("/")
            response.set_cookie(COOKIE, request.query["token"], httponly=True, samesite="Strict")
            raise response
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def _state(self, request: web.Request) -> web.Response:
        return web.Response(text=self.frame(), content_type="application/json")

    async def _world(self, request: web.Request) -> web.Response:
        self.frame()  # drains the feed at most once per period, like /api/state
        world = self.view.world_document()
        if world is None:
            return web.json_response({"error": "no world from the coordinator yet"}, status=404)
        if self._world_json is None or self._world_json[0] != world["version"]:
            self._world_json = (world["version"], json.dumps(world, separators=(",", ":")))
        return web.Response(
            text=self._world_json[1],
            content_type="application/json",
            headers={"Cache-Control": "no-store"},
        )

    async def _map(self, request: web.Request) -> web.Response:
        png = self.view.map_png
        if png is None:
            return web.json_response({"error": "no map picture from the coordinator"}, status=404)
        return web.Response(
            body=png, content_type="image/png", headers={"Cache-Control": "no-store"}
        )

    async def _feed_client(self, ws: web.WebSocketResponse) -> None:
        """Send every new frame to one page; a slow page skips frames, never delays others."""
        seen = 0  # version 0: no frame built yet (its text is empty, no JSON for the page)
        while not ws.closed:
            async with self._changed:
                while self._version == seen:
                    await self._changed.wait()
                text, seen = self._frame, self._version
            await ws.send_str(text)

    async def _stream(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=1024)
        await ws.prepare(request)
        self.clients += 1
        sender = asyncio.create_task(self._feed_client(ws))
        try:
            async for _ in ws:
                pass  # the page sends nothing: steering goes through POST /api/steer
        finally:
            self.clients -= 1
            sender.cancel()
        return ws

    async def _steer_request(self, request: web.Request) -> web.Response:
        if request.content_type != "application/json":
            return self._answer(None, False, "send the request as application/json", 0.0, 415)
        body = await request.read()
        try:
            steer = parse_steer_body(body)
        except BadSteerInput as exc:
            return self._answer(None, False, f"malformed request: {exc}", 0.0, 400)
        if self._steer is None:
            return self._answer(steer, False, "this console cannot steer", 0.0, 503)
        from covswarm.coordinator.steer_client import SteerTimeout
        from covswarm.protocol import ProtocolError

        async with self._steer_lock:  # one at a time, in the order the operator made them
            loop = asyncio.get_running_loop()
            try:
                reply = await loop.run_in_executor(None, self._steer, steer)
            except SteerTimeout as exc:
                return self._answer(steer, False, str(exc), 0.0, 504)
            except ProtocolError as exc:
                return self._answer(steer, False, f"unreadable reply: {exc}", 0.0, 502)
        route = None if reply.route is None else [[float(v) for v in stop] for stop in reply.route]
        return self._answer(steer, reply.accepted, reply.reason, reply.duration, 200, route)

    def _answer(
        self,
        steer: Any,
        accepted: bool,
        reason: str,
        duration: float,
        status: int,
        route: list[list[float]] | None = None,
    ) -> web.Response:
        """Record the outcome for every page and answer the one that asked (``route``: an
        accepted goto's stops [x, y, scale], SteerReply.route)."""
        outcome = {
            "wall": time.time(),
            "request": None if steer is None else steer.to_dict(),
            "what": "unreadable request" if steer is None else steer.describe(),
            "accepted": accepted,
            "reason": reason,
            "duration": duration,
            "route": route,
        }
        self.view.on_steering(outcome)
        if not accepted:
            self._steer_log.warning(
                f"steering {status}", "steering refused (%s): %s", outcome["what"], reason
            )
        return web.json_response(
            {"accepted": accepted, "reason": reason, "duration": duration, "route": route},
            status=status,
        )


def console_url(host: str, port: int, token: str | None) -> str:
    """The URL to open (printed once): the token in the query when one is needed."""
    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    if ":" in shown:
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/" + (f"?token={token}" if token else "")


async def serve(console: Console, host: str, port: int, announce: Callable[[int], None]) -> None:
    """Serve until SIGINT/SIGTERM; ``announce`` gets the bound port once listening."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    runner = web.AppRunner(console.app, access_log=None)
    await runner.setup()
    try:
        site = web.TCPSite(runner, host, port)
        await site.start()
        bound = runner.addresses[0][1]
        announce(bound)
        await stop.wait()
    finally:
        await runner.cleanup()


@click.command("console")
@connect_option("Zenoh endpoint of the swarm's router, e.g. tcp/127.0.0.1:7447 (repeatable).")
@click.option("--swarm", required=True, help="Swarm name (key prefix) of the run to watch.")
@click.option(
    "--host",
    default=DEFAULT_HOST,
    show_default=True,
    help="Address to listen on; anything but 127.0.0.1 (or any with --secure) requires the "
    "printed token.",
)
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=DEFAULT_PORT,
    show_default=True,
    help="TCP port (0: any free one).",
)
@float_option(
    "--rate",
    low=1.0,
    high=60.0,
    default=DEFAULT_RATE,
    help="State frames per second pushed to the page.",
)
@float_option(
    "--steer-timeout",
    low=0.1,
    high=60.0,
    default=2.0,
    help="Seconds to wait for the coordinator's answer to a steering request.",
)
@SECURE_OPTION
@click.option(
    "--token-file",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Take the token from this owner-only file instead of making one, and print the URL "
    "without it (covswarm run --console prints it).",
)
def console_command(
    connect: Sequence[str],
    swarm: str,
    host: str,
    port: int,
    rate: float,
    steer_timeout: float,
    secure: Path | None,
    token_file: Path | None,
) -> None:
    """Serve the operator console of a running swarm: watch it, and steer S by dragging.

    In open mode a console on 127.0.0.1 needs no token; on any other address, and on every
    address with --secure, each request must carry the token of the URL it prints."""
    from covswarm.coordinator.steer_client import SteeringClient
    from covswarm.protocol import check_swarm
    from covswarm.protocol.session import SessionError, open_session, session_config

    logging.basicConfig(level=logging.INFO, format="%(asctime)s console %(message)s")
    try:
        check_swarm(swarm)
        check_host(host)
        config = session_config(list(connect), secure=secure, role="console")
        given = None if token_file is None else read_token_file(str(token_file))
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    token = given or (new_token() if needs_token(host, secure is not None) else None)
    try:
        session = open_session(config)
    except SessionError as exc:
        where = ", ".join(connect)
        raise click.ClickException(f"cannot reach the swarm at {where}: {exc}") from None
    with watch_expiry(secure, "console"), session:  # its certificate's end stops it
        feed = SwarmFeed(session, swarm, SwarmView(swarm))
        client = SteeringClient(session, swarm, timeout=steer_timeout)
        console = Console(feed, client.request, token=token, rate=rate)

        def announce(bound: int) -> None:
            # Printed once, on stdout (the token is a secret: it goes nowhere else); a token
            # from a file is not (stdout may be a log others can read: covswarm run's).
            if given is None:
                url = console_url(host, bound, token)
            else:
                url = f"{console_url(host, bound, None)} (with the token of {token_file})"
            click.echo(f"covswarm console of swarm {swarm}: {url}")
            log.info("listening on %s port %d (%s)", host, bound, "token" if token else "loopback")

        try:
            asyncio.run(serve(console, host, port, announce))
        except OSError as exc:
            raise click.ClickException(f"cannot listen on {host}:{port}: {exc}") from None
