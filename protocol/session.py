"""The Zenoh session configuration every covswarm process uses.

Explicit endpoints only: multicast scouting and gossip are off, so a process talks to the
router it was told about and nothing else (runs on one machine never cross by discovery).
Secured mode (mutual TLS with one certificate per role and id, ``secure=DIR``) is described
in :mod:`protocol.security`; the router's access control in :mod:`protocol.access`.
"""

from __future__ import annotations

import ipaddress
import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import zenoh

from covswarm.protocol.security import (
    CERT,
    ROUTER,
    apply_security,
    check_secure_folder,
    identity_name,
)

MODES = ("client", "peer", "router")
RECONNECT_PERIOD_MS = 1000  # longest wait between attempts to reach a lost router
# Zenoh's link protocols; those of HOST_PORT name a host and a port.
PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock")
HOST_PORT = ("tcp", "tls", "udp", "quic", "ws")
_HOSTNAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9-]{0,62})(\.[A-Za-z0-9]([A-Za-z0-9-]{0,62}))*\.?$")
# Where zenoh's messages say which Rust source raised them: nothing a user can act on.
_RUST_SOURCE = re.compile(r"\s+at /\S+\.rs:\d+\.?")


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` as given if it is a Zenoh endpoint ``<protocol>/<address>`` that zenoh
    can parse, e.g. ``tcp/127.0.0.1:7447``, ``tls/[::1]:7447``, ``tcp/robot-3.lab:7447``
    (metadata after ``?`` or ``#`` kept as is); else ValueError with the reason, before a
    session is configured (zenoh's own error is a JSON5 parse error with a traceback)."""
    if not isinstance(endpoint, str) or not endpoint.strip():
        raise ValueError(f"endpoint {endpoint!r}: empty; expected <protocol>/<address>")
    protocol, slash, address = endpoint.partition("/")
    if not slash or not address:
        raise ValueError(
            f"endpoint {endpoint!r}: expected <protocol>/<address>, e.g. tcp/127.0.0.1:7447"
        )
    if protocol not in PROTOCOLS:
        raise ValueError(
            f"endpoint {endpoint!r}: unknown protocol {protocol!r}; one of {', '.join(PROTOCOLS)}"
        )
    if protocol not in HOST_PORT:
        return endpoint
    host, colon, port = _host_port(endpoint)
    if not colon or not host:
        raise ValueError(f"endpoint {endpoint!r}: expected {protocol}/<host>:<port>")
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"endpoint {endpoint!r}: port {port!r} is not a number in 0..65535")
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise ValueError(f"endpoint {endpoint!r}: {host} is not an IPv6 address") from None
    elif not _HOSTNAME.match(host):
        raise ValueError(
            f"endpoint {endpoint!r}: {host!r} is neither an IP address nor a host name"
            " (an IPv6 address goes in brackets: tcp/[::1]:7447)"
        )
    return endpoint


def _host_port(endpoint: str) -> tuple[str, str, str]:
    """(host, ":" or "", port) of ``<protocol>/<host>:<port>[?metadata][#config]``."""
    address = re.split(r"[?#]", endpoint.partition("/")[2], maxsplit=1)[0]
    return address.rpartition(":")


def is_loopback(endpoint: str) -> bool:
    """Whether ``endpoint`` (checked by :func:`check_endpoint`) is reachable from this host
    only: a loopback address or ``localhost``, or a protocol without a network address
    (a Unix socket, a pipe, a serial line)."""
    if endpoint.partition("/")[0] not in HOST_PORT:
        return True
    host = _host_port(endpoint)[0].strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: it resolves to another host's view of this one
        return False


def check_open_listen(listen: Iterable[str]) -> None:
    """ValueError unless every ``listen`` endpoint of a router in open mode (no --secure) is
    loopback (:func:`is_loopback`): an open router that other hosts can reach lets any of
    them command every robot, publish the domain the team follows and read everything
    (docs/security.md); beyond loopback covswarm listens in secured mode only."""
    exposed = [e for e in listen if not is_loopback(e)]
    if not exposed:
        return
    named = [_host_port(e)[0].strip("[]") for e in exposed]
    hosts = "".join(f" --host {h}" for h in named if h not in ("0.0.0.0", "::"))
    tls = ", ".join(f"tls/{e.partition('/')[2]}" for e in exposed)
    raise ValueError(
        f"{', '.join(exposed)}: a router reachable from other hosts needs --secure DIR "
        "(without it anyone who reaches the port commands every robot). Issue the "
        f"credentials once (covswarm credentials DIR{hosts}), listen on {tls} and give "
        "every process --secure DIR (docs/security.md); or listen on 127.0.0.1"
    )


def check_router_folder(directory: Path, listen: Iterable[str] = ()) -> None:
    """ValueError (one line) unless the secure folder ``directory`` holds what a router of it
    needs (``ca.pem``, ``router/cert.pem`` and ``key.pem``, ``identities.json``) and its
    certificate names every host of ``listen``: what :func:`session_config` checks for a
    router, for a launcher to check before it writes or starts anything."""
    check_secure_folder(directory, ROUTER)
    check_router_hosts(directory, listen)


def check_router_hosts(directory: Path, listen: Iterable[str]) -> None:
    """ValueError unless the router's certificate in the secure folder ``directory`` names
    every host of the ``listen`` endpoints (a wildcard address aside: this host's processes
    reach it on loopback, which it always names): a client connecting to an address the
    certificate does not name is refused with no reason but "Unable to connect"."""
    from covswarm.protocol.certificates import certificate_names  # cryptography: secure only

    names = certificate_names(Path(directory) / ROUTER / CERT)
    for endpoint in listen:
        host = _host_port(endpoint)[0]
        if host in ("0.0.0.0", "[::]") or names.covers(host):
            continue
        named = sorted(n.partition(":")[2] for n in names.alt_names)
        kept = [n for n in named if n not in ("127.0.0.1", "localhost")]  # always named
        hosts = "".join(f" --host {n}" for n in [*kept, host.strip("[]")])
        raise ValueError(
            f"the router's certificate names {', '.join(named)}, not {host}: clients of "
            f"{endpoint} would be refused; covswarm credentials {directory}{hosts} issues "
            "it again with that name"
        )


def zenoh_reason(exc: BaseException) -> str:
    """A zenoh error's message without the Rust source location zenoh appends."""
    return _RUST_SOURCE.sub("", str(exc)).strip()


class SessionError(ConnectionError):
    """A Zenoh session that could not be opened, with zenoh's reason (``covswarm`` prints
    it as a one-line error: covswarm.deploy.cli)."""


def open_session(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(config)``; its failure (no router at the endpoints, a port in use, a
    certificate refused) as SessionError with zenoh's reason."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise SessionError(zenoh_reason(exc)) from None


def session_config(
    connect: list[str] | None,
    listen: list[str] | None = None,
    mode: str = "client",
    *,
    max_sessions: int | None = None,
    secure: Path | None = None,
    role: str = "operator",
    id: int | Sequence[int] | None = None,  # noqa: A002 (the robot id, as on the command line)
) -> zenoh.Config:
    """A zenoh.Config with explicit endpoints and no scouting.

    ``connect``/``listen`` are endpoint lists such as ``["tcp/127.0.0.1:7447"]``. A client
    must connect somewhere; a router must be told where to listen (zenoh's default would be
    every interface). ``max_sessions`` raises the router's client limit (default 1000).
    ``secure`` is a secure folder (protocol.security): mutual TLS, and then every endpoint
    must be ``tls/...`` so that nothing of the swarm travels in clear. The session presents
    the certificate of ``role`` (coordinator, agent, robot, bridge, console, operator) and
    ``id`` (agent and robot only: one id, or the ids of a process running several brains);
    a router presents its own and enforces the access-control list. ``role``/``id`` are
    ignored without ``secure``; without it a router listens on loopback only
    (:func:`check_open_listen`).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if mode == "client" and not connect:
        raise ValueError("a client session needs at least one --connect endpoint")
    if mode == "router" and not listen:
        raise ValueError("a router session needs at least one listen endpoint")
    endpoints = [check_endpoint(e) for e in [*(connect or []), *(listen or [])]]
    if mode != "router":
        identity_name(role, id)  # a wrong role fails in open mode too, not first on a lab
    if secure is not None:
        clear = [e for e in endpoints if not e.startswith("tls/")]
        if clear:
            raise ValueError(f"secured mode needs tls/ endpoints, got {clear}")
    else:
        tls = [e for e in endpoints if e.startswith("tls/")]
        if tls:  # zenoh would only say "Unable to connect"
            raise ValueError(
                f"{', '.join(tls)}: a tls/ endpoint needs --secure DIR (a folder from "
                "covswarm credentials: the CA and this process's certificate)"
            )
        check_open_listen(listen or [])
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
        # A lost router is retried every RECONNECT_PERIOD_MS at most (zenoh's default backs
        # off to 4 s), so every process is back within about a second of a router restart.
        config.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": 250, "period_max_ms": RECONNECT_PERIOD_MS}),
        )
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if max_sessions is not None:
        config.insert_json5("transport/unicast/max_sessions", json.dumps(int(max_sessions)))
    if secure is not None:
        apply_security(config, secure, mode, role, id)
        if mode == "router":
            check_router_hosts(secure, listen or [])
    return config
