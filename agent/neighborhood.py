"""What one agent knows of the robots around it, and which of them it must listen to.

Pure bookkeeping, no I/O: positions arrive as Tracks (from a robot's own pose or
AgentState, a neighbour's relay, or a beacon), age out on receipt time (monotonic seconds,
so clock skew between machines does not matter) and are dead-reckoned with the velocity
they carry. From the Voronoi neighbours of the last control step (``one_hop``) and their
reported neighbours it derives the two-hop set whose AgentStates the agent subscribes to.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Iterable
from collections.abc import Set as AbstractSet
from dataclasses import dataclass

import numpy as np

from covswarm import protocol

# s: at most this far ahead are positions dead-reckoned from a reported velocity. Ages count
# from the sender's stamp (covswarm.agent.brain), so a link 0.3 s late is still compensated.
DEAD_RECKONING_LIMIT = 0.5
LOCAL_MARGIN = 1.25  # local diagram radius, in units of the cell reach (see relevant())
# s: a neighbour whose AgentState has left us out of its neighbours for this long gets an
# early beacon (no relay told it about us; a common neighbour's usually does in a tick).
ASYMMETRY_GRACE = 0.3
FORGET_PERIOD = 1.0  # s between two sweeps of records older than every timeout
# s: a robot known only from its beacon (no pose or AgentState of its own heard since, no
# live liveliness token of its agent) whose AgentState we asked for (subscribed: it is a
# Voronoi neighbour or within the safety radius, see ask()) and did not receive within this
# long is no candidate. A real robot answers within a control period or two; a phantom
# (forged beacons: 36 in a 0.12 m ring around each robot held a team of 6 still for the
# 25 s beacon timeout, issue 21) never does, and then leaves the diagram and the safety
# filter. Counting from the request, not the beacon, keeps the robots that did not matter
# to us (never asked for) as candidates, and is independent of how often the step runs.
BEACON_CONFIRMATION = 1.0
# s: a robot left out so gets another chance with a beacon received this long after we
# first asked for it (the agents' routine beacon period): a real robot whose states were
# lost may come back. Forged beacons repeated with the same ids cost at most 1 s in 10.
CONFIRMATION_RETRY = 10.0

RelayEntry = tuple[int, float, float, float, float]  # id, x, y, vx, vy (AgentState.relay)
Reckoned = tuple[float, float, float, float]  # x, y (m) at the step, vx, vy (m/s)


@dataclass(slots=True)
class Track:
    """Last known position of another robot, when (monotonic) it was received, and the
    velocity its agent reported with it (0 for poses and beacons)."""

    x: float
    y: float
    received: float
    vx: float = 0.0
    vy: float = 0.0


def cell_reach(distance_to_centroid: float, area: float) -> float:
    """Distance within which a robot can cut this cell: twice the cell radius R.

    R is estimated from the cell's centroid c and area A (m^2) as |p - c| + sqrt(A): 1.4x
    the true R of a square cell centred on p, about R for a 4:1 rectangle; the two-hop set
    covers what the estimate misses.
    """
    return 2.0 * (distance_to_centroid + math.sqrt(max(area, 0.0)))


def tile_radius(reach: float, tile_size: float, current: int, max_radius: int) -> int:
    """Beacon tile radius r ((2r+1)^2 tiles) that holds every robot within ``reach``.

    Grows at once, shrinks only with a 25 % margin so a cell hovering at a tile boundary
    does not flap the subscriptions.
    """
    needed = min(max(1, math.ceil(reach / tile_size)), max_radius)
    if needed >= current:
        return needed
    relaxed = min(max(1, math.ceil(1.25 * reach / tile_size)), max_radius)
    return relaxed if relaxed < current else current


def clamp_position(x: float, y: float) -> tuple[float, float]:
    """(x, y) clamped to the wire's coordinate bounds (dead reckoning may overshoot them)."""
    bound = protocol.MAX_COORD
    return min(max(x, -bound), bound), min(max(y, -bound), bound)


def linger(since: dict[int, float], current: Iterable[int], now: float, period: float) -> set[int]:
    """``current`` plus the ids that were in it (``since``: id -> last seen) within ``period``
    s; updates ``since``."""
    for rid in current:
        since[rid] = now
    for rid in [r for r, t in since.items() if now - t > period]:
        del since[rid]
    return set(since)


class Liveliness:
    """The liveliness tokens of the agents and robots seen by one process, each change
    recorded once, numbered (``serial``), for all the brains that share it
    (:meth:`Neighborhood.share`)."""

    def __init__(self) -> None:
        self.serial = 0
        self.deaths: dict[tuple[int, str], int] = {}  # (id, role) -> serial of the deletion
        self.tokens: set[int] = set()  # agents whose token appeared and did not vanish since
        self._appeared: list[tuple[int, int]] = []  # (serial, agent id), oldest first

    def change(self, role: str, rid: int, alive: bool) -> None:
        """Robot ``rid``'s ``role`` ("agent" or "robot"; others are ignored) token appeared
        (``alive``) or vanished."""
        if role not in ("agent", "robot"):
            return
        self.serial += 1
        if not alive:
            self.deaths[rid, role] = self.serial
            if role == "agent":
                self.tokens.discard(rid)
            return
        self.deaths.pop((rid, role), None)
        if role == "agent":
            self.tokens.add(rid)
            self._appeared.append((self.serial, rid))

    def appeared(self, since: int) -> list[int]:
        """The agents whose token appeared after change number ``since``."""
        first = bisect.bisect_right(self._appeared, since, key=lambda entry: entry[0])
        return [rid for _, rid in self._appeared[first:]]

    def trim(self, upto: int) -> None:
        """Forget the appearances up to change number ``upto`` (every follower has them)."""
        del self._appeared[: bisect.bisect_right(self._appeared, upto, key=lambda e: e[0])]


class Neighborhood:
    """The other robots one agent knows of, by how it heard of them.

    Times are monotonic seconds of receipt. ``stale_timeout`` bounds a robot's own pose or
    AgentState and a relay; ``beacon_timeout`` a beacon; ``linger_period`` how long an id
    stays subscribed after it left the two-hop set.
    """

    def __init__(
        self,
        me: int,
        stale_timeout: float,
        beacon_timeout: float,
        linger_period: float,
        confirmation: float = BEACON_CONFIRMATION,
    ) -> None:
        self.me = me
        self.confirmation = confirmation
        self.stale_timeout = stale_timeout
        self.beacon_timeout = beacon_timeout
        self.linger_period = linger_period
        self.poses: dict[int, Track] = {}
        self.state_tracks: dict[int, Track] = {}
        self.beacons: dict[int, Track] = {}
        self._beacons_changed = 0  # beacons added or forgotten (keys the cache below)
        # What refresh() took from the beacons last, while it holds: (key, computed at, the
        # oldest beacon in it (s; valid while fresh), id -> x, y, 0, 0 in the order of
        # ``beacons``, their table rows, id -> row).
        # Most of a brain's candidates are beacon-only robots that change far less often
        # than every control period, and rebuilding them each period was a fifth of it.
        self._beacon_cache: tuple | None = None
        self.neighbor_sets: dict[int, tuple[frozenset[int], float]] = {}
        # relayer id -> (its AgentState.relay entries, when received)
        self.relays: dict[int, tuple[tuple[RelayEntry, ...], float]] = {}
        # id -> (x, y, vx, vy) of every candidate of the last step, reckoned to that step,
        # and the ids among them known first-hand (own pose or AgentState): what our
        # AgentState relays about our neighbours; its keys are the robots usable as
        # candidates at the last step.
        self.reckoned: dict[int, Reckoned] = {}
        self.first_hand: set[int] = set()
        self.table = np.zeros((0, 4))
        self.table_ids = np.zeros(0, dtype=np.int64)
        self._heard: dict[int, float] = {}  # id -> last receipt of its own pose or state
        # The token changes seen (this agent's own, or its process's: share()), the serial
        # of the last one taken as applied (catch_up), and (id, role) -> that serial when
        # data from a robot revived it.
        self.liveliness = Liveliness()
        self._shared = False
        self.mark = 0
        self._revived: dict[tuple[int, str], int] = {}
        # id -> roles ("agent", "robot") whose liveliness token was deleted: such a robot is
        # no team member (a stopped robot without brain, or a brain without robot); as of
        # the last refresh().
        self.dead: dict[int, set[str]] = {}
        # id -> when we first asked for the AgentState of a robot known only from beacons
        # (ask()); the candidates of the last step known only from beacons; those left out
        # of it for want of confirmation (id -> x, y), and how many were so left out in all
        self.asked: dict[int, float] = {}
        self.beacon_only: AbstractSet[int] = set()
        self.unconfirmed: dict[int, tuple[float, float]] = {}
        self.unconfirmed_total = 0
        self.one_hop: frozenset[int] = frozenset()
        self.wanted: dict[int, float] = {}  # id -> last time it was in the two-hop set
        self._unrequited: dict[int, float] = {}  # neighbour id -> since when it omits us
        self._last_forget = -math.inf
        self.stale_dropped = 0  # robots dropped from the candidates because their data aged

    # --- input -------------------------------------------------------------------------

    def on_pose(self, pose: protocol.Pose, now: float) -> None:
        self.poses[pose.id] = Track(pose.x, pose.y, now)
        self._heard[pose.id] = now
        self.asked.pop(pose.id, None)
        self._revive(pose.id, "robot")

    def on_agent_state(self, state: protocol.AgentState, now: float) -> None:
        self.state_tracks[state.id] = Track(state.x, state.y, now, state.vx or 0.0, state.vy or 0.0)
        self._heard[state.id] = now
        self.asked.pop(state.id, None)
        self._revive(state.id, "agent")
        self.neighbor_sets[state.id] = (frozenset(state.neighbors), now)
        if state.relay is None:
            self.relays.pop(state.id, None)
        else:
            self.relays[state.id] = (state.relay, now)

    def on_beacon(self, beacon: protocol.Beacon, now: float) -> None:
        self.beacons[beacon.id] = Track(beacon.x, beacon.y, now)
        self._update_beacon_cache(beacon)
        asked = self.asked.get(beacon.id)
        if asked is not None and now - asked >= CONFIRMATION_RETRY:
            del self.asked[beacon.id]  # another chance (CONFIRMATION_RETRY)
        self._revive(beacon.id, "agent")

    def _update_beacon_cache(self, beacon: protocol.Beacon) -> None:
        """Keep refresh()'s beacon cache valid through a new beacon where it can (a team of
        N hears N / beacon_period of them a second): a beacon-only robot's row moves in
        place (the cache then expires early, with its previous beacon: harmless); a robot
        known otherwise stays out of it while it is; any other one invalidates it."""
        cache = self._beacon_cache
        if cache is not None:
            (_, known, _), _, _, rows, table, index = cache
            row = index.get(beacon.id)
            if row is not None:
                rows[beacon.id] = (beacon.x, beacon.y, 0.0, 0.0)
                table[row, :2] = (beacon.x, beacon.y)
                return
            if beacon.id in known:
                return
        self._beacons_changed += 1

    def share(self, liveliness: Liveliness) -> None:
        """Follow the token changes of ``liveliness``, the process's (covswarm.agent.pack):
        each change is then handled once for all its brains, not once per brain."""
        self.liveliness, self._shared = liveliness, True
        self.mark = liveliness.serial

    def on_liveliness(self, role: str, rid: int, alive: bool) -> bool:
        """A liveliness token of another robot's agent or robot appeared or vanished; True
        when it announces a newcomer (an agent we do not know yet).

        A vanished one takes that robot out of the local diagram at once (SIGKILL deletes the
        token immediately; a frozen process after the Zenoh lease). Fresh data from the same
        role revives it too (a process that came back after a router restart may re-declare
        its token before this agent's subscriber is back), so a missed PUT costs nothing.
        In a packed process the pack records the change in the liveliness it shares
        (:meth:`share`), and each brain :meth:`catch_up` after its turn's data.
        """
        self.liveliness.change(role, rid, alive)
        newcomer = self.catch_up()
        if not self._shared:
            self.liveliness.trim(self.mark)
        return newcomer

    def catch_up(self) -> bool:
        """Take the token changes recorded since the last catch-up as applied from now on
        (data received until now does not revive a robot whose token vanished since);
        True when one announced a newcomer: another agent we do not know yet."""
        liveliness = self.liveliness
        newcomer = any(
            rid != self.me and rid not in self.reckoned for rid in liveliness.appeared(self.mark)
        )
        self.mark = liveliness.serial
        return newcomer

    def _revive(self, rid: int, role: str) -> None:
        if (rid, role) in self.liveliness.deaths:
            self._revived[rid, role] = self.mark

    def _dead(self) -> dict[int, set[str]]:
        """id -> roles whose liveliness token vanished and that nothing revived since."""
        dead: dict[int, set[str]] = {}
        revived = self._revived
        for (rid, role), serial in self.liveliness.deaths.items():
            if rid != self.me and revived.get((rid, role), -1) < serial:
                dead.setdefault(rid, set()).add(role)
        return dead

    # --- what the control step uses ----------------------------------------------------

    def candidates(self, now: float) -> dict[int, tuple[float, float]]:
        """Positions (x, y) m of the other robots known well enough to enter the local
        diagram, reckoned to ``now`` (:meth:`refresh`)."""
        self.refresh(now)
        return {rid: (x, y) for rid, (x, y, _, _) in self.reckoned.items()}

    def refresh(self, now: float) -> None:
        """Reckon the other robots known well enough to enter the local diagram to ``now``:
        ``reckoned`` (id -> x, y, vx, vy) and the same as arrays, ``table`` (n, 4) (m, m/s)
        and ``table_ids`` (n,), for the distance tests of every step.

        In order of trust: the freshest of a robot's own pose and AgentState while younger
        than ``stale_timeout`` (a pose wins a tie); else the freshest relay of it in a
        neighbour's AgentState younger than that; else its beacon while younger than
        ``beacon_timeout``. Positions are dead-reckoned to ``now`` with the reported
        velocity (at most DEAD_RECKONING_LIMIT s): a state is up to a control period old
        when the next step reads it, and at 0.2 m/s that lag alone is a centimetre of
        error in every neighbour.
        """
        fresh = now - self.stale_timeout
        dead = self.dead = self._dead() if self.liveliness.deaths else {}
        chosen: dict[int, Track] = {}
        for table in (self.poses, self.state_tracks):
            for rid, track in table.items():
                if track.received >= fresh:
                    known = chosen.get(rid)
                    if known is None or track.received > known.received:
                        chosen[rid] = track
        reckoned: dict[int, Reckoned] = {}
        for rid, track in chosen.items():
            if rid not in dead:
                lead = min(now - track.received, DEAD_RECKONING_LIMIT)
                reckoned[rid] = (
                    track.x + lead * track.vx,
                    track.y + lead * track.vy,
                    track.vx,
                    track.vy,
                )
        first_hand = set(reckoned)
        skip = first_hand | dead.keys()
        skip.add(self.me)
        # The loops below run over every robot known (~250 at the paper's density), each
        # control period: membership tests rather than dict.get calls, sets built at once.
        relayed: dict[int, float] = {}  # id -> receipt time of the relay used
        for relayer, (entries, received) in self.relays.items():
            if received < fresh or relayer in dead:
                continue
            lead = min(now - received, DEAD_RECKONING_LIMIT)
            for rid, x, y, vx, vy in entries:
                if rid not in skip and (rid not in relayed or relayed[rid] < received):
                    relayed[rid] = received
                    reckoned[rid] = (x + lead * vx, y + lead * vy, vx, vy)
        known = reckoned.keys() | dead.keys()
        # The beacons' part (_from_beacons) depends on nothing but this key and time while
        # no robot awaits confirmation (then none is unconfirmed either): the heard times
        # of the robots not in ``known`` change only as they enter it.
        key = (self._beacons_changed, known, self.liveliness.serial)
        cache = self._beacon_cache
        if (
            cache is not None
            and not self.asked
            and cache[0] == key
            and cache[1] <= now
            and cache[2] >= now - self.beacon_timeout
        ):
            _, _, _, rows, beacon_table, _ = cache
            unconfirmed: dict[int, tuple[float, float]] = {}
        else:
            rows, unconfirmed, first = self._from_beacons(now, known)
            beacon_table = np.array(list(rows.values()), dtype=float).reshape(-1, 4)
            self._beacon_cache = None
            if not self.asked:
                index = {rid: row for row, rid in enumerate(rows)}
                self._beacon_cache = (key, now, first, rows, beacon_table, index)
        self.beacon_only = rows.keys()
        head = np.fromiter(
            itertools.chain.from_iterable(reckoned.values()), dtype=float, count=4 * len(reckoned)
        ).reshape(-1, 4)
        head_ids = np.fromiter(reckoned, dtype=np.int64, count=len(reckoned))
        reckoned.update(rows)
        self.unconfirmed_total += len(unconfirmed.keys() - self.unconfirmed.keys())
        self.unconfirmed = unconfirmed
        self.stale_dropped += len(self.reckoned.keys() - reckoned.keys())
        self.reckoned, self.first_hand = reckoned, first_hand
        self.table = np.concatenate((head, beacon_table))
        self.table_ids = np.concatenate(
            (head_ids, np.fromiter(rows, dtype=np.int64, count=len(rows)))
        )
        if now - self._last_forget >= FORGET_PERIOD:
            self._last_forget = now
            self._forget(now)

    def _from_beacons(
        self, now: float, known: set[int]
    ) -> tuple[dict[int, Reckoned], dict[int, tuple[float, float]], float]:
        """The beacon-only candidates (id -> x, y, 0, 0, in the order of ``beacons``), the
        robots left out for want of confirmation (id -> x, y) and the oldest receipt time
        among the first (s; they hold with the same inputs while it is fresh). A beacon
        only while it is the newest news of its robot (one that went stale after we heard
        its state must not bring back where it was seconds ago); unconfirmed past
        BEACON_CONFIRMATION: no candidate (module notes)."""
        oldest = now - self.beacon_timeout
        rows: dict[int, Reckoned] = {}
        unconfirmed = {}
        heard, asked, tokens = self._heard, self.asked, self.liveliness.tokens
        confirmation, first = self.confirmation, math.inf
        for rid, track in self.beacons.items():
            received = track.received
            if (
                rid not in known
                and received >= oldest
                and (rid not in heard or heard[rid] < received)
            ):
                if rid not in tokens and (now - asked[rid] if rid in asked else 0.0) > confirmation:
                    unconfirmed[rid] = (track.x, track.y)
                else:
                    rows[rid] = (track.x, track.y, 0.0, 0.0)
                    first = min(first, received)
        return rows, unconfirmed, first

    def within(self, x: float, y: float, radius: float) -> np.ndarray:
        """Indices into ``table`` of the candidates within ``radius`` m of (x, y) m."""
        table = self.table
        return np.flatnonzero(np.hypot(table[:, 0] - x, table[:, 1] - y) <= radius)

    def _forget(self, now: float) -> None:
        """Drop records well past their timeout: memory stays bounded, and the tables that
        every step walks hold only the robots heard from lately."""
        recent = 2.0 * max(self.stale_timeout, self.linger_period)
        for table, horizon in (
            (self.poses, recent),
            (self.state_tracks, recent),
            (self.beacons, 2.0 * self.beacon_timeout),
        ):
            for rid in [rid for rid, t in table.items() if now - t.received > horizon]:
                del table[rid]
                self._beacons_changed += 1
        for rid in [rid for rid in self.asked if rid not in self.beacons]:
            del self.asked[rid]
        deaths = self.liveliness.deaths
        for key in [key for key in self._revived if key not in deaths]:
            del self._revived[key]
        for sets in (self.neighbor_sets, self.relays):
            for rid in [rid for rid, (_, t) in sets.items() if now - t > recent]:
                del sets[rid]
        old = now - 2.0 * self.beacon_timeout
        for rid in [rid for rid, t in self._heard.items() if t < old]:
            del self._heard[rid]

    def ask(self, followed: Iterable[int], now: float) -> None:
        """The AgentStates of ``followed`` are subscribed to from ``now`` on: the robots
        among them known only from beacons start their BEACON_CONFIRMATION."""
        for rid in followed:
            if rid in self.beacon_only or rid in self.unconfirmed:
                self.asked.setdefault(rid, now)

    def relevant(
        self, now: float, me: tuple[float, float], reach: float | None
    ) -> dict[int, tuple[float, float]]:
        """The candidates (id -> x, y m, as last reckoned: :meth:`refresh`) that can matter
        to our control, to keep the local diagram small.

        The two-hop set (neighbours' reported neighbours) plus every robot within
        LOCAL_MARGIN x our cell's reach (m) around ``me``: our cell is cut only within
        ``reach``, and since the reach overestimates (1.4x for a square cell) this also
        holds the second ring around us, i.e. our neighbours' neighbours, before their
        AgentStates arrive. Every known robot is used until a first non-empty cell gives a
        reach (``reach`` None).
        """
        reckoned = self.reckoned
        if reach is None:
            return {rid: (x, y) for rid, (x, y, _, _) in reckoned.items()}
        ids = self.table_ids[self.within(*me, LOCAL_MARGIN * reach)].tolist()
        ids += self.two_hop(now) & reckoned.keys()
        return {rid: reckoned[rid][:2] for rid in ids}

    def two_hop(self, now: float) -> frozenset[int]:
        """One-hop neighbours plus their fresh reported neighbours, without ourselves."""
        ids = set(self.one_hop)
        for rid in self.one_hop:
            entry = self.neighbor_sets.get(rid)
            if entry is not None and now - entry[1] <= self.stale_timeout:
                ids |= entry[0]
        ids.discard(self.me)
        return frozenset(ids)

    def wanted_state_ids(self, now: float) -> set[int]:
        """Ids whose AgentState to subscribe to: our one-hop neighbours, and the rest of the
        two-hop set whose positions no fresh relay of a neighbour carries; lingering
        ``linger_period`` s (a robot across a near-degenerate Voronoi vertex comes and goes
        every few ticks, and every declaration is a round of routing updates for the whole
        swarm)."""
        fresh = now - self.stale_timeout
        covered: set[int] = set()
        for rid in self.one_hop:
            relay = self.relays.get(rid)
            if relay is not None and relay[1] >= fresh:
                covered.update(entry[0] for entry in relay[0])
        wanted = self.one_hop | (self.two_hop(now) - covered)
        return linger(self.wanted, wanted, now, self.linger_period)

    def unrequited(self, now: float) -> bool:
        """Whether a neighbour has left us out of its own neighbours for ASYMMETRY_GRACE.

        Voronoi neighbourhood is symmetric, so such a neighbour does not know where we are:
        no relay reached it and our last routine beacon may be 10 s away. Meanwhile both
        cells are wrong where they meet.
        """
        fresh = now - self.stale_timeout
        unrequited = {}
        for rid in self.one_hop:
            entry = self.neighbor_sets.get(rid)
            if entry is not None and entry[1] >= fresh and self.me not in entry[0]:
                unrequited[rid] = self._unrequited.get(rid, now)
        self._unrequited = unrequited
        return any(now - since >= ASYMMETRY_GRACE for since in unrequited.values())

    def relay(self) -> list[RelayEntry]:
        """Our one-hop neighbours known first-hand, as reckoned at the last step (at most
        protocol.MAX_RELAY): only first-hand positions are relayed, since a relayed one
        passed on again would be dead-reckoned once more at every hop, and around a cycle
        of relays forever."""
        reckoned = self.reckoned
        return [
            (rid, *clamp_position(*reckoned[rid][:2]), *reckoned[rid][2:])
            for rid in sorted(self.one_hop & self.first_hand)
        ][: protocol.MAX_RELAY]
