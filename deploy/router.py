"""The launcher's own Zenoh session (an embedded router, or a client of an existing one),
and ``covswarm router``: a router of its own, for a swarm that must outlive its launcher
(``covswarm run --connect``) or span hosts."""

from __future__ import annotations

import logging
import socket
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import click

from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.runtime.options import ENDPOINT

ROUTER_HOST = "127.0.0.1"

log = logging.getLogger("covswarm.launcher")


def free_port(host: str = ROUTER_HOST) -> int:
    """A TCP port nobody listens on right now (bind to port 0 and ask the OS)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def local_endpoint(listen: str) -> str:
    """The endpoint this host's children use to reach a router listening on ``listen``:
    the same, except that a wildcard address (every interface) is reached on loopback."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]"):
        return f"{proto}/{ROUTER_HOST}:{port}"
    return listen


@contextmanager
def zenoh_session(
    connect: str | None,
    max_sessions: int,
    listen: Sequence[str] = (),
    peers: Sequence[str] = (),
    secure: Path | None = None,
) -> Iterator[tuple[Any, str]]:
    """(session, endpoint children connect to): an embedded router, or a client of ``connect``.

    The embedded router listens on ``listen`` (reachable from other hosts) or else on a free
    loopback port; the free port can be taken by someone else between probing and
    listening, so a failed listen is retried on a fresh port. It connects to the routers
    of ``peers`` (other hosts of the swarm; zenoh keeps retrying until they are up), which
    then route between the hosts' processes. ``secure``: mutual TLS, and the
    router enforces the access list of protocol.access (the client session joins as the
    operator); the free loopback port is then a ``tls/`` endpoint.
    """
    from covswarm.protocol.session import SessionError, open_session, session_config

    if connect is not None:
        session = open_session(session_config([connect], secure=secure))
        with _closing(session):
            yield session, connect
        return
    if listen:
        config = session_config(
            list(peers), list(listen), mode="router", max_sessions=max_sessions, secure=secure
        )
        session = open_session(config)
        with _closing(session):
            yield session, local_endpoint(listen[0])
        return
    for attempt in range(5):
        scheme = "tcp" if secure is None else "tls"
        endpoint = f"{scheme}/{ROUTER_HOST}:{free_port()}"
        config = session_config(
            list(peers), [endpoint], mode="router", max_sessions=max_sessions, secure=secure
        )
        try:
            session = open_session(config)
        except SessionError:
            if attempt == 4:
                raise
            continue
        with _closing(session):
            yield session, endpoint
        return


@contextmanager
def _closing(session: Any) -> Iterator[None]:
    """Close ``session`` on the way out; a close that times out is logged, not raised.

    A router whose 2000 clients all leave at once timed out closing (zenoh's "close
    operation timed out"): the run was over and its outputs not yet written.
    """
    import zenoh

    try:
        yield
    finally:
        try:
            session.close()
        except zenoh.ZError as exc:
            log.warning("closing the Zenoh session: %s", exc)


ROUTER_SESSIONS = 4000  # clients a stand-alone router admits: 1000 robots' four processes


@click.command("router")
@click.option(
    "--listen",
    "listen",
    type=ENDPOINT,
    multiple=True,
    required=True,
    help="Endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; beyond loopback, "
    "e.g. tls/0.0.0.0:7447, with --secure).",
)
@click.option(
    "--connect",
    "peers",
    type=ENDPOINT,
    multiple=True,
    help="Another host's router to route to (repeatable).",
)
@click.option(
    "--max-sessions",
    type=click.IntRange(min=1),
    default=ROUTER_SESSIONS,
    show_default=True,
    help="Clients admitted at once.",
)
@SECURE_OPTION
def router_command(
    listen: Sequence[str], peers: Sequence[str], max_sessions: int, secure: Path | None
) -> None:
    """A Zenoh router for covswarm processes until Ctrl-C or SIGTERM: scouting off, and
    with --secure mutual TLS and the access list of protocol.access. Processes join it with
    --connect (``covswarm run --connect`` keeps running across its restarts)."""
    from covswarm.runtime.clock import StopFlag

    logging.basicConfig(level=logging.INFO, format="%(asctime)s router %(message)s")
    with ExitStack() as stack:
        try:
            stack.enter_context(zenoh_session(None, max_sessions, listen, peers, secure=secure))
        except ValueError as exc:  # the session's configuration (secure folder, endpoints)
            raise click.UsageError(str(exc)) from None
        stack.enter_context(watch_expiry(secure, "router"))  # its certificate's end stops it
        stop = StopFlag()
        print(f"router listening on {', '.join(listen)}", flush=True)
        while not stop.is_set():
            stop.sleep(0.2)
