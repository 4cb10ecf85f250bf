"""Decoding of what an agent receives, shared by the brains of one process.

Decoded messages are immutable and a function of their bytes alone, so a pose that five
brains of one process (``covswarm agent --ids``) follow, or the domain that all of them
follow, is parsed and validated once: a packed process (covswarm.agent.pack) decodes each
payload it drains (:func:`heard`) and hands its brains the :class:`Heard`, and brains
handed plain bytes (one by one: AgentBrain.receive, deploy/netsim.py) share one
:class:`MessageDecoder`, whose cache finds bytes decoded already. The decoder also
remembers what the brains derive from the messages they share (a domain's geometry, a
world's model).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import numpy as np

from covswarm import protocol
from covswarm.agent.extrapolation import extrapolate_density, extrapolate_domain
from covswarm.agent.neighborhood import StateFacts, state_facts
from covswarm.tvd.coverage import validate_polygon
from covswarm.tvd.density import Density
from covswarm.world.model import World
from covswarm.world.wire import from_message

MESSAGE_TYPES: dict[str, type[protocol.Message]] = {
    "pose": protocol.Pose,
    "stranded": protocol.Pose,  # a stranded robot's (covswarm.agent.brain.AgentBrain.stranded)
    "state": protocol.AgentState,
    "beacon": protocol.Beacon,
    "domain": protocol.Domain,
    "world": protocol.World,
}
# Sized for a tick's worth of distinct payloads of a 100-brain process.
DECODE_CACHE = 4096
# Domains whose checks are remembered. Brains take their turns one after another, each
# handed every domain sample since its last turn (a pack hands all of them on, in order: up
# to 16): remembering only the last one made every brain check them all again when a tick
# brought two or more (below 20 Hz held, 40-60 us each: 11 % of an agent process at 8 Hz
# held, scripts/live_cpu.py, 27 Nov 2026). Late brains (overload) each get the 16 newest at
# their own turn, spread over seconds of a 20 Hz broadcast: 64 covers 3.2 s of them.
DOMAINS_REMEMBERED = 64


class _ByIdentity:
    """The answers for the last ``size`` objects answered, by identity: the objects are
    held, so no other object can take their ids while they are remembered."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._answers: dict[tuple[int, ...], tuple[tuple[object, ...], object]] = {}

    def get(self, *objects: object) -> tuple[bool, object]:
        """(True, the answer) if one is remembered for exactly these objects."""
        entry = self._answers.get(tuple(map(id, objects)))
        return (False, None) if entry is None else (True, entry[1])

    def put(self, answer: object, *objects: object) -> None:
        self._answers[tuple(map(id, objects))] = (objects, answer)
        if len(self._answers) > self.size:  # the oldest first: dicts keep insertion order
            del self._answers[next(iter(self._answers))]


# A decoded message as a receiver takes it: the message, and for an AgentState its
# StateFacts (None for the other kinds).
Received = tuple[protocol.Message, StateFacts | None]
# What a receiver checks of a payload: (message, its StateFacts or None, None) if valid,
# (None, None, the ProtocolError) if not.
Decoded = tuple[protocol.Message | None, StateFacts | None, protocol.ProtocolError | None]


def _received(kind: str, payload: object) -> Received:
    message = MESSAGE_TYPES[kind].decode(payload)
    return message, state_facts(message) if kind == "state" else None  # type: ignore[arg-type]


class _FirstRead:
    """Heard.decoded: decoded on the first read, then kept as the instance's attribute (a
    non-data descriptor: the attribute wins from then on). Not functools.cached_property,
    which takes a lock on every first read up to Python 3.11."""

    def __get__(self, heard: Any, owner: type | None = None) -> Any:
        if heard is None:
            return self  # read on the class (introspection)
        decoded = heard.__dict__["decoded"] = _checked(_received, heard.kind, bytes(heard))
        return decoded


class Heard(bytes):
    """A payload as a packed process took it off the bus (covswarm.agent.pack), decoded and
    validated once for all the brains that follow its key: ``decoded`` (Decoded), computed
    when a follower first takes it. Equal to its bytes, so what a brain is handed still
    reads as what arrived; a brain takes ``decoded`` instead of looking the bytes up in the
    decoder's cache, once per payload each (~19 a brain-tick in a team 0.2 m apart: 6 % of
    main's brain-tick by py-spy, 27 Nov 2026).

    Not when drained: a payload that a newer one on its key replaces before any follower's
    turn is never decoded. In an overloaded process most are: its robots' poses come at
    20 Hz and each brain steps a few times a second, and decoding every payload drained
    took 9 % of its CPU (1000 robots on two cores, 27 Nov 2026)."""

    kind: str
    decoded: Decoded = _FirstRead()  # type: ignore[assignment]


def heard(kind: str, payload: bytes) -> Heard:
    """``payload`` of ``kind`` as a Heard, decoded when first read, not cached elsewhere (a
    process decodes each payload it drains at most once)."""
    out = Heard(payload)
    out.kind = kind
    return out


def _checked(received: Callable[[str, object], Received], kind: str, payload: object) -> Decoded:
    """``received(kind, payload)`` as Decoded: the ProtocolError returned, not raised, and
    without its frames (a Heard holds it until every follower has taken it)."""
    try:
        return (*received(kind, payload), None)
    except protocol.ProtocolError as exc:
        return None, None, exc.with_traceback(None)


class MessageDecoder:
    """Bytes -> validated messages, with a bounded cache owned by this instance."""

    def __init__(self, cache_size: int = DECODE_CACHE) -> None:
        # (kind, payload bytes) -> Received; ProtocolError if invalid (never cached).
        self._received_bytes = lru_cache(maxsize=cache_size)(_received)
        self._geometry_of = _ByIdentity(DOMAINS_REMEMBERED)
        self._world_of: tuple[protocol.World, World] | None = None
        self._overlap_of = _ByIdentity(DOMAINS_REMEMBERED)
        self._extrapolated: tuple | None = None  # (domain, density, key, answer)

    def decode(self, kind: str, payload: object) -> protocol.Message:
        """The message of ``kind`` in ``payload``; ProtocolError if invalid (never cached)."""
        return self.received(kind, payload)[0]

    def received(self, kind: str, payload: object) -> Received:
        """The message of ``kind`` in ``payload`` and what a receiver takes from it besides
        (Received); ProtocolError if invalid. Bytes are cached."""
        if type(payload) is bytes:
            return self._received_bytes(kind, payload)
        return _received(kind, payload)

    def decoded(self, kind: str, payload: object) -> Decoded:
        """What a receiver checks of ``payload`` (Decoded): as :meth:`received` (bytes
        cached), the ProtocolError returned. A Heard carries its own (``Heard.decoded``)."""
        return _checked(self.received, kind, payload)

    def domain_geometry(self, domain: protocol.Domain) -> Density | None:
        """Check the domain's polygon and parse its density; ValueError if either is invalid.

        The last DOMAINS_REMEMBERED valid domains are remembered: the brains of a process
        receive the same decoded Domain objects, and the polygon check costs more than the
        decoding.
        """
        known, density = self._geometry_of.get(domain)
        if known:
            return density  # type: ignore[return-value]
        validate_polygon(np.array(domain.vertices))
        density = None if domain.density is None else Density.from_dict(domain.density)
        self._geometry_of.put(density, domain)
        return density

    def extrapolated(
        self,
        domain: protocol.Domain,
        density: Density | None,
        elapsed: float,
        max_extrapolation: float,
    ) -> tuple[np.ndarray, np.ndarray, Density | None]:
        """The domain's vertices (k, 2) m and their velocities (k, 2) m/s, and the density,
        ``elapsed`` s after the broadcast (covswarm.agent.extrapolation), read-only.

        The last answer is remembered: the brains of a process that step together share
        one clock reading and hold the same decoded Domain, so they ask the same question,
        and receive the same arrays (a batched step may then build S's geometry once).
        """
        key = (elapsed, max_extrapolation)
        cached = self._extrapolated
        if cached is not None and cached[0] is domain and cached[1] is density:
            if cached[2] == key:
                return cached[3]
        vertices, velocities = extrapolate_domain(domain, elapsed, max_extrapolation)
        vertices.flags.writeable = velocities.flags.writeable = False
        answer = (vertices, velocities, extrapolate_density(density, elapsed, max_extrapolation))
        self._extrapolated = (domain, density, key, answer)
        return answer

    def world_model(self, message: protocol.World) -> World:
        """The model World of a World message (covswarm.world.wire.from_message); ValueError
        if its geometry is refused. The last one is remembered, as for domain_geometry: the
        brains of a process receive the same decoded message every second."""
        if self._world_of is not None and self._world_of[0] is message:
            return self._world_of[1]
        world = from_message(message)
        self._world_of = (message, world)
        return world

    def domain_penetration(self, domain: protocol.Domain, world: World) -> float:
        """How deep (m) the domain's polygon (valid, convex, either orientation) reaches into
        the world's obstacles: the largest, over the obstacles, of the shortest translation
        that separates S from it (0 when S touches none). For two convex polygons that is
        the least overlap of their projections on the edge normals of both (the
        separating-axis theorem). Only obstacles whose bounding box meets S's are looked
        at; the answers for the last DOMAINS_REMEMBERED domains are remembered (the brains of
        a process hold the same world and receive the same Domains, 20 times a second)."""
        known, depth = self._overlap_of.get(domain, world)
        if known:
            return depth  # type: ignore[return-value]
        polygon = np.array(domain.vertices, dtype=float)
        low, high = polygon.min(axis=0), polygon.max(axis=0)
        deepest = 0.0
        for j in world.candidates((low[0], high[0], low[1], high[1])):
            obstacle = world.obstacles[j].vertices
            edges = np.concatenate(
                [np.roll(polygon, -1, axis=0) - polygon, np.roll(obstacle, -1, axis=0) - obstacle]
            )
            # The edges' unit normals (either sign will do: both ends of each are compared).
            normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
            normals /= np.linalg.norm(normals, axis=1)[:, None]
            on_s, on_o = polygon @ normals.T, obstacle @ normals.T  # (k, axes), (m, axes)
            overlap = np.minimum(
                on_s.max(axis=0) - on_o.min(axis=0), on_o.max(axis=0) - on_s.min(axis=0)
            )
            deepest = max(deepest, float(overlap.min()))
        self._overlap_of.put(deepest, domain, world)
        return deepest
