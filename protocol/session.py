"""Process plumbing shared by every covswarm process: Zenoh session config, stop, timing.

Explicit endpoints only: multicast scouting and gossip are off, so a process talks to the
router it was told about and nothing else (runs on one machine never cross by discovery).
Secured mode (TLS + user/password, ``secure=DIR``) is described in :mod:`protocol.security`.
"""

from __future__ import annotations

import json
import math
import secrets
import signal
import time
from collections.abc import Callable
from pathlib import Path

import click
import zenoh

from covswarm.protocol.inbound import MAX_CLOCK_SKEW
from covswarm.protocol.keys import claim_key, claim_selector, parse_ids
from covswarm.protocol.security import apply_security

MODES = ("client", "peer", "router")
RECONNECT_PERIOD_MS = 1000  # longest wait between attempts to reach a lost router


def session_config(
    connect: list[str] | None,
    listen: list[str] | None = None,
    mode: str = "client",
    *,
    max_sessions: int | None = None,
    secure: Path | None = None,
) -> zenoh.Config:
    """A zenoh.Config with explicit endpoints and no scouting.

    ``connect``/``listen`` are endpoint lists such as ``["tcp/127.0.0.1:7447"]``. A client
    must connect somewhere; a router must be told where to listen (zenoh's default would be
    every interface). ``max_sessions`` raises the router's client limit (default 1000).
    ``secure`` is a secure folder (protocol.security): TLS and user/password, and then every
    endpoint must be ``tls/...`` so that nothing of the swarm travels in clear.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if mode == "client" and not connect:
        raise ValueError("a client session needs at least one --connect endpoint")
    if mode == "router" and not listen:
        raise ValueError("a router session needs at least one listen endpoint")
    if secure is not None:
        clear = [e for e in [*(connect or []), *(listen or [])] if not e.startswith("tls/")]
        if clear:
            raise ValueError(f"secured mode needs tls/ endpoints, got {clear}")
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
        apply_security(config, secure, mode)
    return config


def token_exists(session: zenoh.Session, key: str, timeout: float = 1.0) -> bool:
    """True if a liveliness token matching ``key`` is alive (used to refuse duplicate ids).

    Two processes started within the same instant can both pass this check; the launcher
    never does that, and the check exists to catch operator mistakes.
    """
    replies = session.liveliness().get(key, timeout=timeout)
    return any(reply.ok is not None for reply in replies)


def claim(
    session: zenoh.Session, swarm: str, role: str, robot_id: int, timeout: float = 1.0
) -> zenoh.LivelinessToken | None:
    """Claim (role, id) for this process: its token, or None if another process holds it.

    Declare first, then look: every claimant declares a token under its own random nonce
    and then lists the claims on (role, id). Of two processes, the one whose listing the
    router answers after the other's declaration sees it and backs off; two that start
    within one round trip of each other may both back off, but never both run (given the
    router handles each session's messages in order). The caller keeps the token for its
    lifetime; it vanishes when the process dies.
    """
    own = claim_key(swarm, role, robot_id, secrets.token_hex(8))
    token = session.liveliness().declare_token(own)
    replies = session.liveliness().get(claim_selector(swarm, role, robot_id), timeout=timeout)
    others = {str(r.ok.key_expr) for r in replies if r.ok is not None} - {own}
    if others:
        token.undeclare()
        return None
    return token


def claim_or_refuse(
    session: zenoh.Session, swarm: str, role: str, robot_id: int
) -> zenoh.LivelinessToken:
    """``claim`` for a process that must not start without the id: ClickException if taken."""
    token = claim(session, swarm, role, robot_id)
    if token is None:
        raise click.ClickException(f"{role} {robot_id} is already running in swarm {swarm!r}")
    return token


def scaled(clock: Callable[[], float], time_scale: float) -> Callable[[], float]:
    """``clock`` in mission seconds: mission time runs at ``time_scale`` x wall time.

    A simulated swarm too big for the CPU runs slower than real time: every process of a
    run multiplies its monotonic and wall clocks (message stamps included) by the same
    scale, so periods, timeouts, velocities and the robots' integration all stay in
    mission seconds while the wall-clock load drops by the scale. Processes with different
    scales disagree about stamps and drop each other's messages (stamp_future/stamp_old).
    """
    if time_scale == 1.0:
        return clock
    return lambda: clock() * time_scale


MAX_CLOCK_SKEW_OPTION = click.option(
    "--max-clock-skew",
    type=click.FloatRange(min=0.0),
    default=MAX_CLOCK_SKEW,
    show_default=True,
    help="Drop messages stamped more than this (s) ahead of this process's clock.",
)


TIME_SCALE_OPTION = click.option(
    "--time-scale",
    type=click.FloatRange(min=0.0, min_open=True),
    default=1.0,
    show_default=True,
    help="Mission seconds per wall second (< 1: slower than real time, for big simulations); "
    "the same for every process of a run.",
)


def id_selection(robot_id: int | None, ids: str | None) -> list[int]:
    """The ids a robot or agent process runs: ``--id N`` or ``--ids 0-9`` (exactly one)."""
    if (robot_id is None) == (ids is None):
        raise click.UsageError("give exactly one of --id and --ids")
    if robot_id is not None:
        return [robot_id]
    try:
        return parse_ids(ids)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--ids") from None


class StopFlag:
    """Set by SIGINT/SIGTERM so the main loop can exit and close its session cleanly.

    Zenoh callbacks run on background threads that keep a process alive until the session
    is closed, so processes must leave their ``with zenoh.open(...)`` block, not just die.
    The handler only sets a bool: Python runs handlers between bytecodes of the main
    thread, which may be holding any lock at that moment (setting a threading.Event from
    the handler deadlocked a robot that was inside Event.wait). Loops notice the flag at
    their next tick, at most one period late.
    """

    def __init__(self) -> None:
        self._stop = False
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._handle)

    def _handle(self, signum: int, frame: object) -> None:
        self._stop = True

    def set(self) -> None:
        self._stop = True

    def is_set(self) -> bool:
        return self._stop

    def sleep(self, seconds: float) -> None:
        """Sleep (a signal handler runs in between, and the caller then sees the flag)."""
        time.sleep(max(0.0, seconds))


class Ticker:
    """Fixed-rate loop timing on the monotonic clock, with overrun accounting.

    Deadlines advance by whole periods so the average rate holds; after an overrun of more
    than one period the schedule restarts from now instead of bursting to catch up.
    ``time_scale`` s makes the ticker run on mission time (``clock() * s``, see
    :func:`scaled`): ``rate_hz`` ticks per mission second are ``rate_hz * s`` per wall second.
    """

    def __init__(
        self, rate_hz: float, clock: Callable[[], float] = time.monotonic, time_scale: float = 1.0
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate must be positive, got {rate_hz!r}")
        if not (time_scale > 0 and math.isfinite(time_scale)):
            raise ValueError(f"time scale must be positive, got {time_scale!r}")
        self.period = 1.0 / rate_hz
        self._scale = time_scale
        self._clock = scaled(clock, time_scale)
        self._next = self._clock() + self.period
        self.ticks = 0
        self.overruns = 0

    def now(self) -> float:
        """The ticker's clock (mission seconds when scaled)."""
        return self._clock()

    @property
    def deadline(self) -> float:
        """End of the current period (the next tick's scheduled time), on the ticker's clock."""
        return self._next

    def wait(self, stop: StopFlag) -> float:
        """Sleep until the next deadline (or a stop); returns the monotonic time of the tick."""
        now = self._clock()
        if now > self._next:
            self.overruns += 1  # the deadline passed before we were ready to wait for it
        if now > self._next + self.period:
            self._next = now
        else:
            stop.sleep((self._next - now) / self._scale)  # mission seconds -> wall seconds
        self._next += self.period
        self.ticks += 1
        return self._clock()
