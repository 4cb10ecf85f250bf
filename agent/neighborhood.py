"""What one agent knows of the robots around it, and which of them it must listen to.

Pure bookkeeping, no I/O: positions arrive from a robot's own pose or AgentState (kept as
a Record), a neighbour's relay, or a beacon (a Track), age out on receipt time (monotonic
seconds, so clock skew between machines does not matter) and are dead-reckoned with the
velocity they carry. From the Voronoi neighbours of the last control step (``one_hop``) and their
reported neighbours it derives the two-hop set whose AgentStates the agent subscribes to.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Iterable, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from itertools import repeat

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
# What a receiver takes from an AgentState besides the message (state_facts): its id, its
# neighbours as a set, its velocity vx, vy (m/s, 0 when absent), its relay as id -> x, y,
# vx, vy in the relay's order and the set of those ids (None, None without a relay); every
# id the process's one int object for it (_ID).
StateFacts = tuple[
    int, frozenset[int], float, float, dict[int, Reckoned] | None, frozenset[int] | None
]
# An AgentState as :meth:`Neighborhood.on_agent_states` takes it: the message, its
# StateFacts, and its receipt time (monotonic s).
HeardState = tuple[protocol.AgentState, StateFacts, float]
# What a Neighborhood keeps of a robot's last own pose or AgentState: x, y (m), when
# received (monotonic s), vx, vy (m/s, 0 for a pose), and of a state its neighbours and
# relay as in StateFacts (None for a pose). One tuple per state a brain hears (not a Track,
# a neighbour set and a relay): ~16 per brain and control period.
Record = tuple[
    float,
    float,
    float,
    float,
    float,
    frozenset[int] | None,
    dict[int, Reckoned] | None,
    frozenset[int] | None,
]
# id -> the one int object for it in this process (at most protocol.MAX_ID + 1): the ids
# of every message's facts, and so the keys of every brain's records, sets and candidates,
# are the same objects, which set and dict lookups match by identity, without reading the
# ints themselves (a packed process's brains find most of their data out of the cache).
_ID: dict[int, int] = {}


def freshest(pose: Record | None, state: Record | None) -> Record | None:
    """The newer of a robot's own pose and AgentState records (the pose on a tie: it is
    what the robot measured; a state is what its brain reckoned), None without either."""
    if state is None or (pose is not None and pose[2] >= state[2]):
        return pose
    return state


def state_facts(state: protocol.AgentState) -> StateFacts:
    """What every receiver takes from ``state`` besides its fields: the same for all, so a
    process of many brains derives it once per message (covswarm.agent.decoding)."""
    one = _ID.setdefault
    rid = one(state.id, state.id)
    neighbours = frozenset(map(one, state.neighbors, state.neighbors))
    vx, vy, relay = state.vx or 0.0, state.vy or 0.0, state.relay
    if relay is None:
        return rid, neighbours, vx, vy, None, None
    # the relay's ids are distinct (protocol): the dict holds every entry, in order
    entries = {one(r, r): (x, y, ex, ey) for r, x, y, ex, ey in relay}
    return rid, neighbours, vx, vy, entries, frozenset(entries)


@dataclass(slots=True)
class Track:
    """Another robot's position from its last beacon, and when (monotonic) it arrived."""

    x: float
    y: float
    received: float


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


def linger(
    since: dict[int, float], current: AbstractSet[int], now: float, period: float
) -> set[int]:
    """``current`` plus the ids that were in it (``since``: id -> last seen) within ``period``
    s; updates ``since``."""
    since.update(dict.fromkeys(current, now))
    # Every id seen now when none lingers (most periods): no record to read for its age.
    if len(since) > len(current) or not period >= 0.0:
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
        self.robots: set[int] = set()  # the same, robots
        # robots whose token lives while their agent's does not: stopped by their command
        # timeout, or about to be, and moved by no brain (covswarm.agent.brain.stranded)
        self.orphans: set[int] = set()
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
                if rid in self.robots:
                    self.orphans.add(rid)
            else:
                self.robots.discard(rid)
                self.orphans.discard(rid)
            return
        self.deaths.pop((rid, role), None)
        if role == "agent":
            self.tokens.add(rid)
            self.orphans.discard(rid)
            self._appeared.append((self.serial, rid))
        else:
            self.robots.add(rid)
            if rid not in self.tokens:
                self.orphans.add(rid)

    def appeared(self, since: int) -> list[int]:
        """The agents whose token appeared after change number ``since``."""
        first = bisect.bisect_right(self._appeared, since, key=lambda entry: entry[0])
        return [rid for _, rid in self._appeared[first:]]

    @property
    def kept(self) -> int:
        """Appearances kept (those :meth:`trim` has not forgotten yet)."""
        return len(self._appeared)

    def trim(self, upto: int) -> None:
        """Forget the appearances up to change number ``upto`` (every follower has them)."""
        del self._appeared[: bisect.bisect_right(self._appeared, upto, key=lambda e: e[0])]


class BeaconLedger:
    """The beacons of a :class:`Neighborhood` as arrays, slot i the i-th of its ``beacons``
    (their order), beside when each robot's own pose or state was last heard (``heard``,
    which Neighborhood._hear writes in its loop, a call less per state): for refresh()'s
    vectorised choice of the beacon-only candidates: walking ~250 beacons in Python
    whenever the robots known otherwise changed (one control period in ten, 500 packed
    brains) was half of refresh()."""

    def __init__(self, beacons: dict[int, Track], heard: dict[int, float]) -> None:
        n = len(beacons)
        self.n = n  # slots in use (the arrays keep room to append)
        self.slot = {rid: i for i, rid in enumerate(beacons)}
        self.ids = np.fromiter(beacons, dtype=np.int64, count=n)
        self.rows = np.zeros((n, 4))  # x, y (m), 0, 0: a row of Neighborhood.table
        self.rows[:, 0] = np.fromiter((t.x for t in beacons.values()), dtype=float, count=n)
        self.rows[:, 1] = np.fromiter((t.y for t in beacons.values()), dtype=float, count=n)
        self.received = np.fromiter((t.received for t in beacons.values()), dtype=float, count=n)
        self.heard = np.fromiter(
            (heard.get(rid, -math.inf) for rid in beacons), dtype=float, count=n
        )

    def put(self, rid: int, x: float, y: float, received: float, heard: float) -> int:
        """Robot ``rid``'s beacon at (x, y) m received at ``received`` s (a new robot's last,
        as in the dict, with its own data last heard at ``heard``); its slot."""
        slot = self.slot.get(rid)
        if slot is None:
            slot = self.slot[rid] = self.n
            if slot == len(self.ids):
                room = max(16, 2 * slot)
                self.ids, self.rows, self.received, self.heard = (
                    np.concatenate((a, np.zeros((room - slot, *a.shape[1:]), dtype=a.dtype)))
                    for a in (self.ids, self.rows, self.received, self.heard)
                )
            self.ids[slot], self.heard[slot] = rid, heard
            self.n += 1
        rows = self.rows
        rows[slot, 0], rows[slot, 1], self.received[slot] = x, y, received
        return slot

    def usable(self, oldest: float) -> np.ndarray:
        """(n,) bool: the beacons received since ``oldest`` s and after their robot's own
        pose or state (a beacon only while it is its robot's newest news)."""
        received = self.received[: self.n]
        return (received >= oldest) & (self.heard[: self.n] < received)


@dataclass(slots=True)
class BeaconChoice:
    """The beacon-only candidates refresh() chose (Neighborhood._from_beacons). Most of a
    brain's candidates are such robots, and the same ones from one control period to the
    next: a beacon that moves one of them updates it in place (on_beacon), and the choice
    is taken again as it is while ``current``, its oldest beacon fresh and the robots known
    otherwise the same."""

    ledger: BeaconLedger
    mask: bytes  # the ledger's slots chosen, (n,) bool
    slots: np.ndarray  # (m,) of them
    rows: dict[int, Reckoned]  # id -> x, y, 0, 0 in slot order
    table: np.ndarray  # (m, 4) the same as table rows
    ids: np.ndarray  # (m,) their ids
    known: AbstractSet[int] = frozenset()  # robots known otherwise: none of them chosen
    first: float = math.inf  # s: the oldest receipt of a beacon chosen
    # False once a beacon or state arrived that may change the choice (a new robot's, or
    # one of them heard first-hand), or while robots await confirmation (ask())
    current: bool = False


class Neighborhood:
    """The other robots one agent knows of, by how it heard of them.

    Times are monotonic seconds of receipt. ``stale_timeout`` bounds a robot's own pose or
    AgentState and a relay; ``beacon_timeout`` a beacon; ``linger_period`` how long an id
    stays subscribed after it left the two-hop set; ``reckoning_limit`` how far ahead a
    reported velocity is followed (DEAD_RECKONING_LIMIT, longer for a brain stepped
    late: covswarm.agent.brain.AgentBrain.pace), and ``at_rest_after`` how long after its
    stamp a robot is taken as stopped (velocity 0: its command timed out before the next;
    never, unless brains are stepped less often than commands last).
    """

    def __init__(
        self,
        me: int,
        stale_timeout: float,
        beacon_timeout: float,
        linger_period: float,
        confirmation: float = BEACON_CONFIRMATION,
    ) -> None:
        if not confirmation >= 0.0:
            raise ValueError(f"beacon confirmation must be >= 0 s, not {confirmation}")
        self.me = me
        self.confirmation = confirmation
        self.stale_timeout = stale_timeout
        self.reckoning_limit = DEAD_RECKONING_LIMIT
        self.at_rest_after = math.inf
        self.beacon_timeout = beacon_timeout
        self.linger_period = linger_period
        self.poses: dict[int, Record] = {}
        self.states: dict[int, Record] = {}
        self.beacons: dict[int, Track] = {}
        self._heard: dict[int, float] = {}  # id -> last receipt of its own pose or state
        self._ledger = BeaconLedger(self.beacons, self._heard)
        self._choice: BeaconChoice | None = None  # the beacon-only candidates chosen last
        # relayer id -> its record in ``states`` while its last AgentState had a relay (in
        # the order they gained one: refresh()'s order of relays)
        self.relays: dict[int, Record] = {}
        # id -> (x, y, vx, vy) of every candidate of the last step, reckoned to that step,
        # and the ids among them known first-hand (own pose or AgentState): what our
        # AgentState relays about our neighbours; its keys are the robots usable as
        # candidates at the last step.
        self.reckoned: dict[int, Reckoned] = {}
        self.first_hand: set[int] = set()
        self.table = np.zeros((0, 4))
        self.table_ids = np.zeros(0, dtype=np.int64)
        # (x, y) -> distances (n,) m of the rows of ``table`` from there: a step asks for
        # the robots around its pose more than once (local set, followed ids, safety).
        self._distances: dict[tuple[float, float], np.ndarray] = {}
        # The token changes seen (this agent's own, or its process's: share()), the serial
        # of the last one taken as applied (catch_up), and (id, role) -> that serial when
        # data from a robot revived it.
        self.liveliness = Liveliness()
        self._shared = False
        self.mark = 0
        self._revived: dict[tuple[int, str], int] = {}
        self._revivals = 0  # changes of _revived: with the liveliness serial, keys ``dead``
        self._dead_key: tuple = ()
        # id -> roles ("agent", "robot") whose liveliness token was deleted: such a robot is
        # no team member (a stopped robot without brain, or a brain without robot); as of
        # the last refresh().
        self.dead: dict[int, set[str]] = {}
        # id -> when we first asked for the AgentState of a robot known only from beacons
        # (ask()); the candidates of the last step known only from beacons; those left out
        # of it for want of confirmation (id -> x, y), and how many were so left out in all
        self.asked: dict[int, float] = {}
        self.beacon_only: AbstractSet[int] = set()
        # The dict whose keys are beacon_only, those of them moved (on_beacon) since, and
        # the other candidates of the last step, in their order in ``reckoned``.
        self._beacon_only: dict[int, Reckoned] = {}
        self._moved: list[int] = []
        self._head_ids: list[int] = []
        self._dead_known: dict[int, set[str]] = {}  # ``dead`` at the last refresh
        self.unconfirmed: dict[int, tuple[float, float]] = {}
        self.unconfirmed_total = 0
        self.one_hop: frozenset[int] = frozenset()
        self.wanted: dict[int, float] = {}  # id -> last time it was in the two-hop set
        self._unrequited: dict[int, float] = {}  # neighbour id -> since when it omits us
        self._last_forget = -math.inf
        self.stale_dropped = 0  # robots dropped from the candidates because their data aged

    # --- input -------------------------------------------------------------------------

    def on_pose(self, pose: protocol.Pose, now: float) -> None:
        rid = pose.id
        self.poses[rid] = (pose.x, pose.y, now, 0.0, 0.0, None, None, None)
        self._hear(((pose, None, now),))
        if self.liveliness.deaths:
            self._revive(rid, "robot")

    def on_agent_state(self, state: protocol.AgentState, now: float) -> None:
        self.on_agent_states(((state, state_facts(state), now),))

    def on_agent_states(self, states: Sequence[HeardState]) -> None:
        """AgentStates in order, each with its state_facts and receipt time: as
        :meth:`on_agent_state` one by one, in one call (a packed brain receives ~6 per
        control period, and this is the bulk of its receive path)."""
        records, relays = self.states, self.relays
        revive = bool(self.liveliness.deaths)  # token changes apply between turns only
        for state, (rid, neighbours, vx, vy, entries, ids), now in states:
            record = records[rid] = (state.x, state.y, now, vx, vy, neighbours, entries, ids)
            if revive:
                self._revive(rid, "agent")
            if entries is None:
                relays.pop(rid, None)
            else:
                relays[rid] = record
        self._hear(states)

    def _hear(self, heard: Iterable[tuple[protocol.Message, object, float]]) -> None:
        """Robots' own poses or states arrived: (message, anything, receipt time) each."""
        times, asked, choice = self._heard, self.asked, self._choice
        slots, ledger_heard = self._ledger.slot, self._ledger.heard  # the ledger's, inline
        for message, _, now in heard:
            rid = message.id
            times[rid] = now
            slot = slots.get(rid)
            if slot is not None:
                ledger_heard[slot] = now
            if asked:
                asked.pop(rid, None)
            if choice is not None and rid in choice.rows:
                choice.current = False  # its beacon is no longer its newest news

    def on_beacon(self, beacon: protocol.Beacon, now: float) -> None:
        rid, x, y = beacon.id, beacon.x, beacon.y
        self.beacons[rid] = Track(x, y, now)
        slot = self._ledger.put(rid, x, y, now, self._heard.get(rid, -math.inf))
        choice = self._choice
        if choice is not None and rid in choice.rows:
            # A beacon-only candidate moved (a team of N hears N / beacon_period beacons a
            # second): in place, as refresh() would choose it again.
            choice.rows[rid] = (x, y, 0.0, 0.0)
            self._moved.append(rid)
            row = int(choice.slots.searchsorted(slot))
            choice.table[row, 0], choice.table[row, 1] = x, y
        elif choice is not None and rid not in choice.known:
            choice.current = False  # a robot that may now be chosen
        asked = self.asked.get(rid)
        if asked is not None and now - asked >= CONFIRMATION_RETRY:
            del self.asked[rid]  # another chance (CONFIRMATION_RETRY)
        if self.liveliness.deaths:
            self._revive(rid, "agent")

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
        if liveliness.serial == self.mark:
            return False  # no change since (most turns)
        newcomer = any(
            rid != self.me and rid not in self.reckoned for rid in liveliness.appeared(self.mark)
        )
        self.mark = liveliness.serial
        return newcomer

    def _revive(self, rid: int, role: str) -> None:
        if (rid, role) in self.liveliness.deaths:
            self._revived[rid, role] = self.mark
            self._revivals += 1

    def dead_now(self) -> dict[int, set[str]]:
        """:attr:`dead` brought up to the token changes recorded so far (and kept)."""
        self.dead = self._dead() if self.liveliness.deaths else {}
        return self.dead

    def _dead(self) -> dict[int, set[str]]:
        """id -> roles whose liveliness token vanished and that nothing revived since: the
        last one while no token changed and no data revived a robot."""
        key = (self.liveliness, self.liveliness.serial, self._revivals)
        if key == self._dead_key:
            return self.dead
        self._dead_key = key
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
        velocity (at most ``reckoning_limit`` s, and ``at_rest_after``, when its robot
        stopped, its velocity then 0: first-hand or relayed alike): a state is up to a
        control period old when the next step reads it, and at 0.2 m/s that lag alone is a
        centimetre of error in every neighbour.
        """
        fresh = now - self.stale_timeout
        rest = self.at_rest_after
        # A position is reckoned as far as its velocity is followed and its robot drives it:
        # one heard longer than ``rest`` ago stopped then.
        limit = min(self.reckoning_limit, rest)
        dead = self.dead_now()
        records = self.states.items()
        if self.poses:  # other robots' poses (rarely: a brain follows its own robot's)
            chosen = {rid: pose for rid, pose in self.poses.items() if pose[2] >= fresh}
            for rid, record in records:
                if record[2] >= fresh and freshest(chosen.get(rid), record) is record:
                    chosen[rid] = record
            records = chosen.items()
        reckoned: dict[int, Reckoned] = {}
        # Fields by index, not unpacked: only those read are touched (a packed process's
        # records are mostly out of the cache by its brain's step).
        for rid, record in records:
            received = record[2]
            if received >= fresh and rid not in dead:
                lead = now - received
                vx, vy = record[3], record[4]
                if lead > limit:
                    x, y = record[0] + limit * vx, record[1] + limit * vy
                    if lead > rest:
                        vx = vy = 0.0
                    reckoned[rid] = (x, y, vx, vy)
                else:
                    reckoned[rid] = (record[0] + lead * vx, record[1] + lead * vy, vx, vy)
        first_hand = set(reckoned)
        skip = first_hand | dead.keys()
        skip.add(self.me)
        # The loops below run over every robot known (~250 at the paper's density), each
        # control period: membership tests rather than dict.get calls, sets built at once.
        # A relay names mostly robots known first-hand (our own neighbours'): the set
        # difference (in C, over its ids, by identity: _ID) leaves the few to reckon.
        relayed: dict[int, float] = {}  # id -> receipt time of the relay used
        for relayer, record in self.relays.items():
            received = record[2]
            if received < fresh or relayer in dead:
                continue
            new = record[7] - skip  # type: ignore[operator]
            if not new:
                continue
            lead = now - received
            moving = lead <= rest
            if lead > limit:
                lead = limit
            entries: dict[int, Reckoned] = record[6]  # type: ignore[assignment]
            for rid in entries:  # in the relay's order
                if rid in new and (rid not in relayed or relayed[rid] < received):
                    relayed[rid] = received
                    x, y, vx, vy = entries[rid]
                    x, y = x + lead * vx, y + lead * vy
                    if not moving:
                        vx = vy = 0.0
                    reckoned[rid] = (x, y, vx, vy)
        head = np.fromiter(
            itertools.chain.from_iterable(reckoned.values()), dtype=float, count=4 * len(reckoned)
        ).reshape(-1, 4)
        head_ids_list, choice = list(reckoned), self._choice
        same_head = head_ids_list == self._head_ids
        if (
            choice is not None
            and same_head
            and (dead is self._dead_known or not (dead or self._dead_known))
        ):
            known = choice.known  # the same robots as at the last step (most steps)
        else:
            known = reckoned.keys() | dead.keys()
        self._dead_known = dead
        rows, beacon_table, beacon_ids, unconfirmed = self._from_beacons(now, known)
        if unconfirmed:
            self.unconfirmed_total += len(unconfirmed.keys() - self.unconfirmed.keys())
        self.unconfirmed = unconfirmed
        last = self.reckoned
        if rows is self._beacon_only and same_head:
            # The same candidates in the same order as at the last step (most steps): new
            # values in place, rather than a new dict of them all (~250), which touched
            # every beacon-only candidate's tuple in memory each period (a packed process
            # holds too many brains for its cache).
            last.update(reckoned)
            for rid in self._moved:
                last[rid] = rows[rid]
            reckoned = last
            # and the table's rows too (the same layout): a new one cost more than them
            self.table[: len(head)] = head
            if self._moved:
                self.table[len(head) :] = beacon_table
        else:
            reckoned.update(rows)
            if rows is self._beacon_only:  # the same beacon-only ones: none of them dropped
                self.stale_dropped += sum(rid not in reckoned for rid in self._head_ids)
            else:
                self.stale_dropped += len(last.keys() - reckoned.keys())
            self.table = np.concatenate((head, beacon_table))
            head_ids = np.fromiter(head_ids_list, dtype=np.int64, count=len(head_ids_list))
            self.table_ids = np.concatenate((head_ids, beacon_ids))
        self._moved.clear()
        self._beacon_only, self.beacon_only, self._head_ids = rows, rows.keys(), head_ids_list
        self.reckoned, self.first_hand = reckoned, first_hand
        self._distances = {}
        if now - self._last_forget >= FORGET_PERIOD:
            self._last_forget = now
            self._forget(now)

    def _from_beacons(
        self, now: float, known: AbstractSet[int]
    ) -> tuple[dict[int, Reckoned], np.ndarray, np.ndarray, dict[int, tuple[float, float]]]:
        """The beacon-only candidates: id -> x, y, 0, 0 in the order of ``beacons``, the
        same as table rows (m, 4) and ids (m,); and the robots left out for want of
        confirmation (id -> x, y). A beacon only while younger than ``beacon_timeout`` and
        the newest news of its robot (one that went stale after we heard its state must
        not bring back where it was seconds ago), and of none in ``known``; unconfirmed
        past BEACON_CONFIRMATION: no candidate (module notes)."""
        ledger, choice, oldest = self._ledger, self._choice, now - self.beacon_timeout
        if (
            choice is not None
            and choice.current
            and not self.asked
            and choice.ledger is ledger
            and choice.first >= oldest
            and (choice.known is known or choice.known == known)
        ):
            return choice.rows, choice.table, choice.ids, {}
        usable = ledger.usable(oldest)
        slot = ledger.slot
        usable[[slot[rid] for rid in known if rid in slot]] = False
        unconfirmed: dict[int, tuple[float, float]] = {}
        if self.asked:
            tokens, confirmation = self.liveliness.tokens, self.confirmation
            late = sorted(
                (slot[rid], rid)
                for rid, asked in self.asked.items()
                if now - asked > confirmation
                and rid not in tokens
                and rid in slot
                and usable[slot[rid]]
            )
            for _, rid in late:
                track = self.beacons[rid]
                unconfirmed[rid] = (track.x, track.y)
            usable[[s for s, _ in late]] = False
        mask = usable.tobytes()
        if choice is None or choice.ledger is not ledger or choice.mask != mask:
            slots = np.flatnonzero(usable)
            table = ledger.rows[slots]
            ids = ledger.ids[slots]
            xs, ys = table[:, 0].tolist(), table[:, 1].tolist()
            rows = dict(zip(ids.tolist(), zip(xs, ys, repeat(0.0), repeat(0.0)), strict=False))
            choice = self._choice = BeaconChoice(ledger, mask, slots, rows, table, ids)
        choice.known = known
        choice.first = float(ledger.received[choice.slots].min(initial=math.inf))
        choice.current = not self.asked
        return choice.rows, choice.table, choice.ids, unconfirmed

    def fresh_rows(self, rows: np.ndarray, now: float, horizon: float) -> np.ndarray:
        """``rows`` (increasing indices into ``table``) without the robots known only from
        a beacon that arrived more than ``horizon`` s before ``now`` while their AgentState
        is on its way: not asked for yet, or asked for less than ``confirmation`` s ago
        (AgentBrain._safety_inputs). Such a beacon says where its robot was; a robot riding
        S has moved on, and its AgentState, asked for as it comes near (ask), says where it
        is. One whose state does not come (a live agent token keeps it a candidate) is a
        row again from then on."""
        first = int(np.searchsorted(rows, len(self._head_ids)))  # the beacon-only rows on
        if first == len(rows):
            return rows
        awaited = self._awaited
        stale = [
            k
            for k, rid in enumerate(self.table_ids[rows[first:]].tolist(), start=first)
            if awaited(rid, now, horizon)
        ]
        return np.delete(rows, stale) if stale else rows

    def _awaited(self, rid: int, now: float, horizon: float) -> bool:
        """Whether beacon-only robot ``rid`` is no row for :meth:`fresh_rows`: its beacon
        is older than ``horizon`` s and its AgentState not asked for, or asked for less
        than ``confirmation`` s ago."""
        track = self.beacons.get(rid)
        return track is None or (
            now - track.received > horizon and now - self.asked.get(rid, now) <= self.confirmation
        )

    def stop_point(self, rid: int, after: float) -> tuple[float, float] | None:
        """Where robot ``rid`` stands (x, y) m if it drove on the velocity of its freshest
        first-hand record (its AgentState's, or a pose's, at rest) for ``after`` s from it and
        then stopped: a robot whose brain stalled, ``after`` its command timeout. None
        without a record."""
        record = freshest(self.poses.get(rid), self.states.get(rid))
        if record is None:
            return None
        return record[0] + after * record[3], record[1] + after * record[4]

    def within(self, x: float, y: float, radius: float) -> np.ndarray:
        """Indices into ``table`` of the candidates within ``radius`` m of (x, y) m."""
        distance = self._distances.get((x, y))
        if distance is None:
            table = self.table
            distance = self._distances[x, y] = np.hypot(table[:, 0] - x, table[:, 1] - y)
        return (distance <= radius).nonzero()[0]

    def _forget(self, now: float) -> None:
        """Drop records well past their timeout: memory stays bounded, and the tables that
        every step walks hold only the robots heard from lately."""
        recent = 2.0 * max(self.stale_timeout, self.linger_period)
        for records in (self.poses, self.states, self.relays):
            for rid in [rid for rid, record in records.items() if now - record[2] > recent]:
                del records[rid]
        ledger = self._ledger
        old = ledger.ids[: ledger.n][now - ledger.received[: ledger.n] > 2.0 * self.beacon_timeout]
        for rid in old.tolist():
            del self.beacons[rid]
        for rid in [rid for rid in self.asked if rid not in self.beacons]:
            del self.asked[rid]
        deaths = self.liveliness.deaths
        for key in [key for key in self._revived if key not in deaths]:
            del self._revived[key]
        unheard = [rid for rid, t in self._heard.items() if t < now - 2.0 * self.beacon_timeout]
        for rid in unheard:
            del self._heard[rid]
        if len(old) or any(rid in ledger.slot for rid in unheard):
            self._ledger = BeaconLedger(self.beacons, self._heard)

    def ask(self, followed: Iterable[int], now: float) -> None:
        """The AgentStates of ``followed`` are subscribed to from ``now`` on: the robots
        among them known only from beacons start their BEACON_CONFIRMATION."""
        beacon_only, unconfirmed, asked = self.beacon_only, self.unconfirmed, self.asked
        for rid in followed:
            if rid in beacon_only or rid in unconfirmed:
                asked.setdefault(rid, now)

    def relevant(
        self,
        now: float,
        me: tuple[float, float],
        reach: float | None,
        ahead: float = 0.0,
        trust: float = math.inf,
    ) -> dict[int, tuple[float, float]]:
        """The candidates (id -> x, y m, as last reckoned: :meth:`refresh`, and ``ahead`` s
        further with their velocities) that can matter to our control, to keep the local
        diagram small.

        The two-hop set (neighbours' reported neighbours) plus every robot within
        LOCAL_MARGIN x our cell's reach (m) around ``me``: our cell is cut only within
        ``reach``, and since the reach overestimates (1.4x for a square cell) this also
        holds the second ring around us, i.e. our neighbours' neighbours, before their
        AgentStates arrive. Every known robot is used until a first non-empty cell gives a
        reach (``reach`` None).

        Without the robots known only from a beacon older than ``trust`` s whose AgentState
        is awaited (:meth:`fresh_rows`, the safety filter's rule): a robot riding S beacons
        every 10 s, and its old spot, metres behind it, is no robot. Two hops away, where
        we never ask for its state, such a phantom bent our neighbours' cells, and through
        TVD-DA's coupling our own velocity: 20 robots through the warehouse held e_a at
        8-10 mm, against 2 mm without them (deploy.netsim, seeds 0-2, 3 Dec 2026).
        """
        reckoned = self.reckoned
        if reach is None:
            ids = list(reckoned)
        else:
            rows = self.fresh_rows(self.within(*me, LOCAL_MARGIN * reach), now, trust)
            ids = self.table_ids[rows].tolist()
            beacon_only, awaited = self.beacon_only, self._awaited
            ids += [
                rid
                for rid in self.two_hop(now) & reckoned.keys()
                if rid not in beacon_only or not awaited(rid, now, trust)
            ]
        if not ahead:
            return {rid: reckoned[rid][:2] for rid in ids}
        moved = {}
        for rid in ids:
            x, y, vx, vy = reckoned[rid]
            moved[rid] = (x + ahead * vx, y + ahead * vy)
        return moved

    def two_hop(self, now: float) -> frozenset[int]:
        """One-hop neighbours plus their fresh reported neighbours, without ourselves."""
        one_hop, states, stale = self.one_hop, self.states, self.stale_timeout
        ids = set(one_hop)
        for rid in one_hop:
            if rid in states:
                record = states[rid]
                if now - record[2] <= stale:
                    ids |= record[5]  # type: ignore[arg-type]
        ids.discard(self.me)
        return frozenset(ids)

    def wanted_state_ids(self, now: float, near: AbstractSet[int] = frozenset()) -> set[int]:
        """Ids whose AgentState to subscribe to: our one-hop neighbours, and the rest of the
        two-hop set and of ``near`` (the robots our safety filter needs) whose positions and
        velocities no fresh relay of a neighbour carries; lingering ``linger_period`` s (a
        robot across a near-degenerate Voronoi vertex comes and goes every few ticks, and
        every declaration is a round of routing updates for the whole swarm).

        A relay is a neighbour's first-hand view of its own neighbours at its last step, one
        AgentState interval older than a state of their own: in a dense team it carries most
        of the robots within SAFETY_RADIUS, whose own states were over half of what a brain
        received (17 of 19 payloads a tick at 0.2 m spacing; 8 without them)."""
        fresh = now - self.stale_timeout
        relays = self.relays
        covered = set().union(  # the relays' id sets, in C
            *[relays[r][7] for r in self.one_hop if r in relays and relays[r][2] >= fresh]
        )
        wanted = self.one_hop | ((self.two_hop(now) | near) - covered)
        return linger(self.wanted, wanted, now, self.linger_period)

    def unrequited(self, now: float) -> bool:
        """Whether a neighbour has left us out of its own neighbours for ASYMMETRY_GRACE.

        Voronoi neighbourhood is symmetric, so such a neighbour does not know where we are:
        no relay reached it and our last routine beacon may be 10 s away. Meanwhile both
        cells are wrong where they meet.
        """
        fresh, me, states = now - self.stale_timeout, self.me, self.states
        since = self._unrequited
        unrequited = {}
        for rid in self.one_hop:
            if rid in states:
                record = states[rid]
                if record[2] >= fresh and me not in record[5]:  # type: ignore[operator]
                    unrequited[rid] = since.get(rid, now)
        self._unrequited = unrequited
        return bool(unrequited) and now - min(unrequited.values()) >= ASYMMETRY_GRACE

    def relay(self) -> list[RelayEntry]:
        """Our one-hop neighbours known first-hand, as reckoned at the last step (at most
        protocol.MAX_RELAY): only first-hand positions are relayed, since a relayed one
        passed on again would be dead-reckoned once more at every hop, and around a cycle
        of relays forever."""
        reckoned, bound = self.reckoned, protocol.MAX_COORD
        relay = []
        for rid in sorted(self.one_hop & self.first_hand)[: protocol.MAX_RELAY]:
            x, y, vx, vy = reckoned[rid]
            if not (-bound <= x <= bound and -bound <= y <= bound):  # NaN too: as it is
                x, y = clamp_position(x, y)
            relay.append((rid, x, y, vx, vy))
        return relay
