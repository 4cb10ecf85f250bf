"""Neighborhood.refresh() and within() keep state from one call to the next (the beacon
ledger, the beacon-only candidates, ``reckoned`` updated in place, the dead, distances):
over random sequences of inputs they must give what the rules give from scratch, here a
brute-force restatement of them over the records the neighbourhood holds; and so must what
a control step asks of them after each refresh (relevant, two_hop, wanted_state_ids,
unrequited, relay)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from covswarm import protocol
from covswarm.agent.neighborhood import (
    ASYMMETRY_GRACE,
    DEAD_RECKONING_LIMIT,
    LOCAL_MARGIN,
    Neighborhood,
    state_facts,
)

STALE, BEACON, LINGER = 0.5, 2.0, 0.4  # s: short, so that random steps cross every timeout
IDS = range(1, 13)  # few, so that every robot is heard of in several ways


def reference(nb: Neighborhood, now: float) -> tuple[dict, set, set, dict, dict]:
    """(reckoned, first_hand, beacon_only, dead, unconfirmed) of ``nb`` at ``now``, by the
    rules of Neighborhood.refresh's docstring, from its records alone."""
    deaths, revived = nb.liveliness.deaths, nb._revived
    dead: dict[int, set[str]] = {}
    for (rid, role), serial in deaths.items():
        if rid != nb.me and revived.get((rid, role), -1) < serial:
            dead.setdefault(rid, set()).add(role)
    fresh = now - nb.stale_timeout
    chosen = {}  # the freshest of pose and state, a pose on a tie
    # records: x, y, received, vx, vy, neighbours, relay (id -> x, y, vx, vy), relay ids
    for records in (nb.poses, nb.states):
        for rid, (x, y, t, vx, vy, *_) in records.items():
            if t >= fresh and (rid not in chosen or t > chosen[rid][1]):
                chosen[rid] = ((x, y, vx, vy), t)
    reckoned = {}
    for rid, ((x, y, vx, vy), t) in chosen.items():
        if rid not in dead:
            lead = min(now - t, DEAD_RECKONING_LIMIT)
            reckoned[rid] = (x + lead * vx, y + lead * vy, vx, vy)
    first_hand = set(reckoned)
    newest: dict[int, float] = {}
    for relayer, (_, _, received, _, _, _, relay, ids) in nb.relays.items():
        if received < fresh or relayer in dead:
            continue
        assert relay is not None and nb.states[relayer][6] is relay and ids == set(relay)
        lead = min(now - received, DEAD_RECKONING_LIMIT)
        for rid, (x, y, vx, vy) in relay.items():
            taken = rid in first_hand or rid in dead or rid == nb.me
            if not taken and newest.get(rid, -math.inf) < received:
                newest[rid] = received
                reckoned[rid] = (x + lead * vx, y + lead * vy, vx, vy)
    known = set(reckoned) | set(dead)
    beacon_only = set()
    unconfirmed = {}
    for rid, track in nb.beacons.items():
        heard = nb._heard.get(rid, -math.inf)
        if rid in known or track.received < now - nb.beacon_timeout or heard >= track.received:
            continue
        asked = nb.asked.get(rid)
        if rid not in nb.liveliness.tokens and asked is not None and now - asked > nb.confirmation:
            unconfirmed[rid] = (track.x, track.y)
        else:
            reckoned[rid] = (track.x, track.y, 0.0, 0.0)
            beacon_only.add(rid)
    return reckoned, first_hand, beacon_only, dead, unconfirmed


def two_hop_reference(nb: Neighborhood, now: float) -> set[int]:
    """Our one-hop neighbours and their neighbours reported within ``stale_timeout``."""
    ids = set(nb.one_hop)
    for rid in nb.one_hop:
        if rid in nb.states and now - nb.states[rid][2] <= nb.stale_timeout:
            ids |= nb.states[rid][5]
    return ids - {nb.me}


def check_step_queries(nb: Neighborhood, now: float, rng: random.Random) -> None:
    """relevant, wanted_state_ids, unrequited and relay of ``nb`` at ``now`` (after its
    refresh) against their rules, restated over its records."""
    reckoned = dict(nb.reckoned)
    # relevant: the candidates within LOCAL_MARGIN x reach, in table order, then the rest
    # of the two-hop set, each at its reckoned position
    me, reach = _xy(rng), rng.uniform(0.1, 2.0)
    relevant = nb.relevant(now, me, reach)
    near = [
        rid for rid, (x, y, _, _) in reckoned.items()
        if math.hypot(x - me[0], y - me[1]) <= LOCAL_MARGIN * reach
    ]  # fmt: skip
    assert list(relevant)[: len(near)] == near
    assert set(relevant) == set(near) | (two_hop_reference(nb, now) & reckoned.keys())
    assert all(relevant[rid] == reckoned[rid][:2] for rid in relevant)
    assert nb.relevant(now, me, None) == {rid: v[:2] for rid, v in reckoned.items()}
    # with a trust horizon: less the beacon-only robots whose beacon is older than it while
    # their AgentState is awaited (fresh_rows' rule, below), in the diagram's ring and in
    # the two-hop set alike
    trust = rng.choice((0.0, 0.3, 1.0))
    awaited = {
        rid for rid in nb.beacon_only
        if now - nb.beacons[rid].received > trust
        and now - nb.asked.get(rid, now) <= nb.confirmation
    }  # fmt: skip
    trusted = nb.relevant(now, me, reach, trust=trust)
    assert trusted == {rid: xy for rid, xy in relevant.items() if rid not in awaited}
    assert nb.two_hop(now) == two_hop_reference(nb, now)
    # wanted_state_ids: one-hop, and two-hop ids no fresh relay of a neighbour carries,
    # lingering
    fresh = now - nb.stale_timeout
    covered = {
        entry
        for rid in nb.one_hop
        if rid in nb.relays and nb.relays[rid][2] >= fresh
        for entry in nb.relays[rid][6]
    }
    current = set(nb.one_hop) | (two_hop_reference(nb, now) - covered)
    since = {rid: t for rid, t in nb.wanted.items() if now - t <= nb.linger_period}
    since |= dict.fromkeys(current, now)
    assert nb.wanted_state_ids(now) == set(since) and nb.wanted == since
    # unrequited: neighbours whose fresh neighbour set omits us, since when
    earlier = dict(nb._unrequited)
    omitting = {
        rid: earlier.get(rid, now)
        for rid in nb.one_hop
        if rid in nb.states and nb.states[rid][2] >= fresh and nb.me not in nb.states[rid][5]
    }
    late = any(now - t >= ASYMMETRY_GRACE for t in omitting.values())
    assert nb.unrequited(now) == late and nb._unrequited == omitting
    # relay: one-hop neighbours known first-hand, by id, positions within the wire's bounds
    bound = protocol.MAX_COORD
    expected = [
        (rid, min(max(x, -bound), bound), min(max(y, -bound), bound), vx, vy)
        for rid in sorted(nb.one_hop & nb.first_hand)
        for x, y, vx, vy in [reckoned[rid]]
    ][: protocol.MAX_RELAY]
    assert nb.relay() == expected
    # fresh_rows: rows within a radius, less the beacon-only robots whose beacon is older
    # than the horizon and whose AgentState is awaited (not asked for, or asked for less
    # than the confirmation time ago)
    rows = nb.within(*me, rng.uniform(0.0, 3.0))
    horizon = rng.choice((0.0, 0.3, 1.0))
    kept = [
        row for row, rid in zip(rows.tolist(), nb.table_ids[rows].tolist(), strict=True)
        if rid not in nb.beacon_only
        or now - nb.beacons[rid].received <= horizon
        or now - nb.asked.get(rid, now) > nb.confirmation
    ]  # fmt: skip
    assert nb.fresh_rows(rows, now, horizon).tolist() == kept


def _relay(rng: random.Random) -> tuple | None:
    if rng.random() < 0.2:
        return None
    ids = rng.sample(IDS, rng.randint(0, 5)) + [0] * (rng.random() < 0.2)  # 0: ourselves
    if rng.random() < 0.5:  # agents relay by id; the order received is kept all the same
        ids.sort()
    return tuple((rid, *_xy(rng), *_v(rng)) for rid in ids)


def _xy(rng: random.Random) -> tuple[float, float]:
    return rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)


def _v(rng: random.Random) -> tuple[float, float]:
    return rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)


def _step(nb: Neighborhood, rng: random.Random, now: float) -> None:
    """One random input to ``nb`` at ``now``."""
    rid, kind = rng.choice(IDS), rng.random()
    x, y = _xy(rng)
    if kind < 0.15:
        nb.on_pose(protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=1.0, seq=0), now)
    elif kind < 0.4:
        vx, vy = _v(rng) if rng.random() < 0.8 else (None, None)
        neighbors = tuple(sorted(rng.sample(IDS, rng.randint(0, 4)) + [0] * rng.randint(0, 1)))
        state = protocol.AgentState(
            id=rid, x=x, y=y, stamp=1.0, neighbors=neighbors, vx=vx, vy=vy, relay=_relay(rng)
        )
        nb.on_agent_state(state, now)
    elif kind < 0.75:
        nb.on_beacon(protocol.Beacon(id=rid, x=x, y=y, stamp=1.0), now)
    elif kind < 0.85:
        nb.on_liveliness(rng.choice(("agent", "robot")), rid, alive=rng.random() < 0.4)
    elif kind < 0.95:
        nb.ask(rng.sample(IDS, rng.randint(1, 6)), now)
    else:
        nb.one_hop = frozenset(rng.sample(IDS, rng.randint(0, 5)))


@pytest.mark.parametrize("seed", range(12))
def test_refresh_and_within_equal_the_rules_from_scratch(seed: int) -> None:
    rng = random.Random(seed)
    nb = Neighborhood(0, STALE, BEACON, LINGER)
    now, dropped, unconfirmed_total = 0.0, 0, 0
    last_reckoned: set[int] = set()
    last_unconfirmed: set[int] = set()
    last_point = (0.0, 0.0)
    for _ in range(400):
        for _ in range(rng.choice((0, 1, 1, 2, 6))):
            _step(nb, rng, now)
            now += rng.choice((0.0, 0.0, 0.0, 0.2, 0.7))  # some go stale before the refresh
        nb.refresh(now)
        reckoned, first_hand, beacon_only, dead, unconfirmed = reference(nb, now)
        assert list(nb.reckoned.items()) == list(reckoned.items())  # order: table rows
        assert nb.first_hand == first_hand and nb.beacon_only == beacon_only
        assert nb.dead == dead
        assert list(nb.unconfirmed.items()) == list(unconfirmed.items())
        assert nb.table.tolist() == [list(v) for v in reckoned.values()]
        assert nb.table_ids.tolist() == list(reckoned)
        dropped += len(last_reckoned - reckoned.keys())
        unconfirmed_total += len(unconfirmed.keys() - last_unconfirmed)
        last_reckoned, last_unconfirmed = set(reckoned), set(unconfirmed)
        assert nb.stale_dropped == dropped and nb.unconfirmed_total == unconfirmed_total
        # within: from the last refresh's point, twice from a new one (the second from the
        # distances kept), each against every row's distance
        point = _xy(rng)
        for x, y in (last_point, point, point):
            radius = rng.uniform(0.0, 3.0)
            expected = [
                i for i, (rx, ry, _, _) in enumerate(reckoned.values())
                if math.hypot(rx - x, ry - y) <= radius
            ]  # fmt: skip
            assert nb.within(x, y, radius).tolist() == expected
        last_point = point
        check_step_queries(nb, now, rng)
        now += rng.choice((0.0, 0.05, 0.1, 0.1, 0.3, 0.6, 1.1, 2.5))


def test_the_cache_is_exercised() -> None:
    """The sequences above keep the beacon-only candidates from one refresh to the next
    and update ``reckoned`` in place, and also rebuild them: the comparison above covers
    both paths."""
    rng = random.Random(0)
    nb = Neighborhood(0, STALE, BEACON, LINGER)
    kept = rebuilt = in_place = 0
    now = 0.0
    for _ in range(400):
        for _ in range(rng.choice((0, 1, 1, 2))):
            _step(nb, rng, now)
        before, rows_before = nb.reckoned, nb._choice
        nb.refresh(now)
        kept += rows_before is not None and nb._choice is rows_before
        rebuilt += nb._choice is not rows_before
        in_place += nb.reckoned is before
        now += rng.choice((0.0, 0.05, 0.1))
    assert kept > 50 and rebuilt > 50 and in_place > 20


def test_a_negative_confirmation_is_refused() -> None:
    with pytest.raises(ValueError, match="confirmation"):
        Neighborhood(0, STALE, BEACON, LINGER, confirmation=-1.0)


def test_beacon_rows_follow_a_moved_beacon_between_refreshes() -> None:
    """A beacon-only candidate's new beacon moves it at the next refresh, not before (the
    brain reads ``reckoned`` and ``table`` between refreshes)."""
    nb = Neighborhood(0, STALE, BEACON, LINGER)
    for rid in (1, 2, 3):
        nb.on_beacon(protocol.Beacon(id=rid, x=float(rid), y=0.0, stamp=1.0), 0.0)
    nb.refresh(0.1)
    table = nb.table.copy()
    nb.on_beacon(protocol.Beacon(id=2, x=2.0, y=1.5, stamp=1.0), 0.2)
    assert nb.reckoned[2] == (2.0, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(nb.table, table)
    nb.refresh(0.2)
    assert list(nb.reckoned.items()) == [
        (1, (1.0, 0.0, 0.0, 0.0)),
        (2, (2.0, 1.5, 0.0, 0.0)),
        (3, (3.0, 0.0, 0.0, 0.0)),
    ]
    assert nb.within(2.0, 1.5, 0.1).tolist() == [1]


def test_relay_clamps_a_position_reckoned_past_the_wire_bounds() -> None:
    """Dead reckoning may carry a neighbour past protocol.MAX_COORD: relayed clamped, the
    velocity as reported."""
    nb = Neighborhood(0, STALE, BEACON, LINGER)
    bound = protocol.MAX_COORD
    for rid, x, y, vx, vy in ((1, bound - 0.01, -bound + 0.01, 0.2, -0.2), (2, 1.0, 2.0, 0.1, 0.0)):
        state = protocol.AgentState(id=rid, x=x, y=y, stamp=1.0, neighbors=(), vx=vx, vy=vy)
        nb.on_agent_state(state, 0.0)
    nb.one_hop = frozenset({1, 2})
    nb.refresh(0.3)
    assert nb.reckoned[1][0] > bound and nb.reckoned[1][1] < -bound
    assert nb.relay() == [(1, bound, -bound, 0.2, -0.2), (2, 1.0 + 0.3 * 0.1, 2.0, 0.1, 0.0)]


def test_state_facts_give_each_id_one_object() -> None:
    """Two AgentStates decoded apart name their robots with the same int objects (what
    makes refresh()'s set difference an identity test), as robots ids of equal value."""
    ids = (300, 301, 40000)  # beyond the ints that Python shares anyway
    facts = []
    for x in (0.5, 0.7):
        state = protocol.AgentState(
            id=ids[0], x=x, y=0.0, stamp=1.0, neighbors=ids[1:],
            relay=tuple((rid, x, 0.0, 0.0, 0.0) for rid in ids[2:0:-1]),
        )  # fmt: skip
        facts.append(state_facts(protocol.AgentState.decode(state.encode())))
    (rid, neighbours, _, _, relay, relayed), (rid2, neighbours2, _, _, relay2, relayed2) = facts
    assert rid == ids[0] and rid is rid2
    assert neighbours == set(ids[1:]) and all(any(a is b for b in neighbours2) for a in neighbours)
    assert list(relay) == [40000, 301] and list(relay2) == list(relay)
    assert [a is b for a, b in zip(relay, relay2, strict=True)] == [True, True]
    assert relayed == set(relay) and relay[301] == (0.5, 0.0, 0.0, 0.0)
