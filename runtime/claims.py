"""Id claims: at most one process runs a given (role, id) in a swarm (liveliness tokens)."""

from __future__ import annotations

import secrets
import time

import click
import zenoh

from covswarm.protocol.keys import alive_key, claim_key, claim_selector


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


# s between a sole claimant's two looks at the claims: far above a loopback or LAN round
# trip, so a claimant that declared while the first look was under way is seen by the second.
SETTLE = 0.3


def claim_exclusive(
    session: zenoh.Session, swarm: str, role: str, ident: int, settle: float = SETTLE
) -> zenoh.LivelinessToken | None:
    """Claim (role, id) so that of claimants started together exactly one runs: its token,
    or None if another process wins or already runs (for the coordinator, of which a
    swarm has one).

    Every claimant declares a token whose nonce begins with its start time (ns since the
    epoch), then looks at the claims twice, ``settle`` s apart; it backs off if it sees a
    claim older than its own or a live ``alive`` token of (role, id). The oldest claimant
    never backs off and every other one sees it by the second look (it declared before
    that look started), so two processes started together leave exactly one running (not
    none, as :func:`claim` may); one started while another runs sees that one's claim or
    its ``alive`` token. Clocks of different hosts must agree to better than their start
    times differ, or the later one's alive check is what refuses it.
    """
    nonce = f"{time.time_ns():020d}{secrets.token_hex(4)}"
    own = claim_key(swarm, role, ident, nonce)
    token = session.liveliness().declare_token(own)
    for look in range(2):
        if look:
            time.sleep(settle)
        replies = session.liveliness().get(claim_selector(swarm, role, ident), timeout=1.0)
        others = {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}
        older = any(other < nonce for other in others - {nonce})
        if older or token_exists(session, alive_key(swarm, role, ident)):
            token.undeclare()
            return None
    return token
