"""Who may use the console: the token rule, and the checks every HTTP/WebSocket request passes.

In open mode the console listens on 127.0.0.1 by default and then needs no token, like any
local tool; listening on any other address (even another loopback one) needs a token, made
once at start-up and printed once in the URL, like Jupyter. A secured console (``--secure``)
needs its token on every address, loopback included: its steering requests carry the
console's certificate, which no other local user holds, so the page must not lend it to
whoever reaches the port. Pure functions (no aiohttp), so the rules are unit-tested
directly; console.server applies them to every request.

Where a request may carry the token: the ``token`` query parameter (the printed URL), an
``Authorization: token <T>`` header (scripts), or the cookie the page gets on its first
valid load (so its assets, WebSocket and steering requests carry it without putting it in
every URL). Compared in constant time.

Also, with or without a token: a browser page from another site must not steer the swarm
through the operator's browser. Steering and the WebSocket therefore require an ``Origin``
(when the browser sends one) naming the console itself, and steering requires a JSON
content type, which a cross-site form cannot send without a CORS preflight that the console
never answers. Without a token the ``Host`` header must be a loopback name, which stops DNS
rebinding (a hostile name that resolves to 127.0.0.1).
"""

from __future__ import annotations

import hmac
import os
import secrets
from collections.abc import Mapping
from urllib.parse import urlsplit

DEFAULT_HOST = "127.0.0.1"
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
COOKIE = "covswarm_console_token"
TOKEN_BYTES = 24  # 192 random bits, URL-safe (32 characters)


def needs_token(host: str, secure: bool = False) -> bool:
    """True for a secured console (``secure``: it steers with the swarm's credentials)
    whatever its address; in open mode, unless it listens on the default loopback address
    (or its aliases)."""
    return secure or host.strip("[]").lower() not in LOOPBACK_NAMES


def read_token_file(path: str) -> str:
    """The token in the file at ``path`` (one line, written by whoever prints the URL, e.g.
    ``covswarm run --console``), or ValueError: a file that cannot be read, an empty one, or
    one that others may read (a token any local user can read protects nothing)."""
    try:
        info = os.stat(path)
        with open(path, encoding="ascii") as file:
            token = file.read().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the token file {path}: {exc}") from None
    if info.st_mode & 0o077:
        raise ValueError(f"the token file {path} is readable by others: chmod 600 it")
    if not token or any(c.isspace() for c in token):
        raise ValueError(f"the token file {path} holds no token (one word on one line)")
    return token


def check_host(host: str) -> str:
    """``host`` to listen on, or ValueError for an empty one: aiohttp takes "" for every
    interface, which the one who typed it may not mean (and the URL printed would name no
    host); every interface is 0.0.0.0 (or ::), said as such."""
    if not host.strip():
        raise ValueError("an empty address: give one (0.0.0.0 for every interface, with a token)")
    return host


def new_token() -> str:
    """A fresh random token for one console's lifetime."""
    return secrets.token_urlsafe(TOKEN_BYTES)


def presented_token(
    query: Mapping[str, str], headers: Mapping[str, str], cookies: Mapping[str, str]
) -> str | None:
    """The token a request carries (query, then Authorization header, then cookie), or None."""
    if query.get("token"):
        return query["token"]
    scheme, _, value = headers.get("Authorization", "").partition(" ")
    if scheme.lower() in ("token", "bearer") and value.strip():
        return value.strip()
    return cookies.get(COOKIE) or None


def token_ok(expected: str | None, presented: str | None) -> bool:
    """True if no token is required, or ``presented`` equals it (constant-time)."""
    if expected is None:
        return True
    if presented is None:
        return False
    return hmac.compare_digest(expected.encode(), presented.encode())


def _hostname(netloc: str) -> str:
    """The host of a ``host[:port]`` or ``[v6]:port`` header value, lower-case."""
    return (urlsplit(f"//{netloc}").hostname or "").lower()


def host_ok(host_header: str | None, token_required: bool) -> bool:
    """Without a token the Host header must name loopback (no DNS rebinding)."""
    if token_required:
        return True  # the token protects; any name that reaches the console will do
    return host_header is not None and _hostname(host_header) in LOOPBACK_NAMES


def origin_ok(origin: str | None, host_header: str | None) -> bool:
    """A browser request's Origin must be the console's own (scheme://Host); absent is fine.

    Browsers send Origin on every WebSocket handshake and cross-site POST, so a page of
    another site steering through the operator's browser is refused; scripts send none.
    """
    if origin is None:
        return True
    if host_header is None:
        return False
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host_header.lower()


def refusal(
    *,
    expected_token: str | None,
    query: Mapping[str, str],
    headers: Mapping[str, str],
    cookies: Mapping[str, str],
    state_changing: bool,
) -> tuple[int, str] | None:
    """Why a request is refused, as (HTTP status, reason), or None to serve it.

    ``state_changing``: steering and the WebSocket (Origin checked); any other request
    only needs the Host and the token.
    """
    host = headers.get("Host")
    if not host_ok(host, expected_token is not None):
        return 403, f"Host {host!r} is not a loopback name"
    if not token_ok(expected_token, presented_token(query, headers, cookies)):
        return 403, "missing or wrong token: open the URL the console printed at start-up"
    if state_changing and not origin_ok(headers.get("Origin"), host):
        return 403, f"Origin {headers.get('Origin')!r} is not this console"
    return None
