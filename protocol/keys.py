"""Zenoh key expressions of the covswarm wire protocol, defined once.

Every key lives under ``covswarm/<swarm>/``; the swarm name is unique per run by default so
that two runs sharing a router never see each other's traffic. Builders validate their
arguments (ValueError) so a malformed id can never produce a key that silently matches the
wrong subscribers.
"""

from __future__ import annotations

import math
import re
import secrets

PREFIX = "covswarm"
ROLES = ("agent", "robot", "coordinator")
MAX_ID = 65535  # robot ids are 0..MAX_ID

# One key chunk: no "/" and none of the characters zenoh reserves for wildcards/selectors.
_SWARM_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def new_swarm_name() -> str:
    """A fresh random swarm name, so concurrent runs (and test runs) never cross."""
    return f"run-{secrets.token_hex(5)}"


def check_swarm(swarm: str) -> str:
    """Return ``swarm`` if it is a valid single key chunk, else raise ValueError."""
    if not isinstance(swarm, str) or not _SWARM_RE.match(swarm):
        raise ValueError(f"invalid swarm name {swarm!r}: use 1-64 chars of [A-Za-z0-9_.-]")
    return swarm


def check_id(robot_id: int) -> int:
    """Return ``robot_id`` if it is an int in 0..MAX_ID, else raise ValueError."""
    if isinstance(robot_id, bool) or not isinstance(robot_id, int):
        raise ValueError(f"robot id must be an int, got {robot_id!r}")
    if not 0 <= robot_id <= MAX_ID:
        raise ValueError(f"robot id {robot_id} outside 0..{MAX_ID}")
    return robot_id


def parse_ids(spec: str) -> list[int]:
    """Robot ids from a range list such as ``"0-49"`` or ``"0-4,10,12-13"``: sorted, unique.

    How an operator names the slice of the team one host or one process runs; ValueError on
    anything else (empty, reversed range, id outside 0..MAX_ID).
    """
    ids: set[int] = set()
    for part in str(spec).split(","):
        first, dash, last = part.strip().partition("-")
        try:
            lo = _parse_int_chunk(first.strip())
            hi = _parse_int_chunk(last.strip()) if dash else lo
        except ValueError as exc:
            raise ValueError(f"invalid id list {spec!r} ({exc}): use e.g. 0-49 or 0-4,10") from None
        if hi < lo:
            raise ValueError(f"invalid id range {part.strip()!r} in {spec!r}")
        ids.update(range(lo, hi + 1))
    return sorted(ids)


def format_ids(ids: list[int]) -> str:
    """The shortest range list for ``ids`` (inverse of :func:`parse_ids`), e.g. "0-4,10"."""
    parts: list[str] = []
    ordered = sorted(set(ids))
    start = 0
    for k in range(1, len(ordered) + 1):
        if k == len(ordered) or ordered[k] != ordered[k - 1] + 1:
            lo, hi = ordered[start], ordered[k - 1]
            parts.append(str(lo) if lo == hi else f"{lo}-{hi}")
            start = k
    return ",".join(parts)


def _base(swarm: str) -> str:
    return f"{PREFIX}/{check_swarm(swarm)}"


def pose_key(swarm: str, robot_id: int) -> str:
    """Robot process (or real-robot bridge) -> Pose."""
    return f"{_base(swarm)}/robot/{check_id(robot_id)}/pose"


def cmd_key(swarm: str, robot_id: int) -> str:
    """Agent -> WheelCommand for its robot."""
    return f"{_base(swarm)}/robot/{check_id(robot_id)}/cmd"


def domain_key(swarm: str) -> str:
    """Coordinator -> Domain broadcast."""
    return f"{_base(swarm)}/domain"


def status_key(swarm: str) -> str:
    """Coordinator -> Status broadcast."""
    return f"{_base(swarm)}/status"


def world_key(swarm: str) -> str:
    """Coordinator -> World broadcast (the arena; repeated every second)."""
    return f"{_base(swarm)}/world"


def world_map_key(swarm: str) -> str:
    """Console -> coordinator: a query for the occupancy map's picture (a MapImage)."""
    return f"{_base(swarm)}/world/map"


def steer_key(swarm: str) -> str:
    """Client -> coordinator: SteerRequest queries, answered with a SteerReply."""
    return f"{_base(swarm)}/steer"


def agent_state_key(swarm: str, robot_id: int) -> str:
    """Agent -> AgentState (position, neighbour ids, stats)."""
    return f"{_base(swarm)}/agent/{check_id(robot_id)}/state"


def tile_of(x: float, y: float, tile_size: float) -> tuple[int, int]:
    """Beacon tile of a position: ``floor(position / tile_size)`` per axis."""
    if not (tile_size > 0 and math.isfinite(tile_size)):
        raise ValueError(f"tile_size must be positive and finite, got {tile_size!r}")
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"position must be finite, got ({x!r}, {y!r})")
    return math.floor(x / tile_size), math.floor(y / tile_size)


def _check_tile(t: int) -> int:
    if isinstance(t, bool) or not isinstance(t, int):
        raise ValueError(f"tile index must be an int, got {t!r}")
    return t


def beacon_key(swarm: str, tx: int, ty: int, robot_id: int) -> str:
    """Agent -> Beacon, published under the tile that contains its position."""
    return f"{_base(swarm)}/beacon/{_check_tile(tx)}/{_check_tile(ty)}/{check_id(robot_id)}"


def beacon_tile_selector(swarm: str, tx: int, ty: int) -> str:
    """All beacons in one tile (subscribe to the 3x3 tiles around you)."""
    return f"{_base(swarm)}/beacon/{_check_tile(tx)}/{_check_tile(ty)}/*"


def alive_key(swarm: str, role: str, robot_id: int) -> str:
    """Liveliness token of one process; the coordinator uses id 0."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    return f"{_base(swarm)}/alive/{role}/{check_id(robot_id)}"


def claim_key(swarm: str, role: str, robot_id: int, nonce: str) -> str:
    """Liveliness token by which one process claims (role, id) from its start.

    ``nonce`` is random per process, so two claimants of the same id hold distinct tokens
    and each can see the other (see runtime.claims.claim).
    """
    if not (nonce.isascii() and nonce.isalnum()):
        raise ValueError(f"claim nonce must be ASCII letters and digits, got {nonce!r}")
    return f"{claim_selector(swarm, role, robot_id)[:-2]}/{nonce}"


def claim_selector(swarm: str, role: str, robot_id: int) -> str:
    """Every claim on (role, id)."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    return f"{_base(swarm)}/claim/{role}/{check_id(robot_id)}/*"


def alive_selector(swarm: str, role: str | None = None) -> str:
    """Liveliness tokens of one role, or of every role when ``role`` is None."""
    if role is None:
        return f"{_base(swarm)}/alive/*/*"
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    return f"{_base(swarm)}/alive/{role}/*"


def all_poses_selector(swarm: str) -> str:
    """Every robot's pose (coordinator / recorder only: agents subscribe per id)."""
    return _every_id(swarm, "pose")


def all_cmds_selector(swarm: str) -> str:
    """Every wheel command (monitoring only)."""
    return _every_id(swarm, "cmd")


def all_agent_states_selector(swarm: str) -> str:
    """Every agent's state (coordinator / recorder only)."""
    return _every_id(swarm, "state")


# kind -> (words at positions 2 and 4) of "covswarm/<swarm>/<word>/<id>/<word>"
_ID_KEYS = {"pose": ("robot", "pose"), "cmd": ("robot", "cmd"), "state": ("agent", "state")}


def _every_id(swarm: str, kind: str) -> str:
    """The selector of ``kind``'s key (an _ID_KEYS kind) for every robot id."""
    group, leaf = _ID_KEYS[kind]
    return f"{_base(swarm)}/{group}/*/{leaf}"


def _parse_int_chunk(chunk: str) -> int:
    if not (chunk.isascii() and chunk.isdigit()):
        raise ValueError(f"not an id: {chunk!r}")
    return check_id(int(chunk))


def parse_id(key: str, swarm: str, kind: str) -> int:
    """Robot id from a concrete key of ``kind`` in "pose" | "cmd" | "state" | "beacon".

    Raises ValueError if the key does not have that shape.
    """
    parts = str(key).split("/")
    if kind == "beacon":
        ok = len(parts) == 6 and parts[2] == "beacon"
    elif kind in _ID_KEYS:
        ok = len(parts) == 5 and (parts[2], parts[4]) == _ID_KEYS[kind]
    else:
        raise ValueError(f"unknown key kind {kind!r}")
    if not ok or parts[0] != PREFIX or parts[1] != swarm:
        raise ValueError(f"not a {kind} key of swarm {swarm!r}: {key!r}")
    return _parse_int_chunk(parts[-1] if kind == "beacon" else parts[3])


class KeyIds:
    """Robot ids of the keys of one kind (:func:`parse_id`) as a subscriber of a wildcard
    meets them, each key parsed once: ``ids(key)`` is its id, None for a key of another
    shape. A message's own id is to be held against it: in secure mode a process may put
    only on its own keys, never inside another robot's messages (docs/security.md). At
    most ``limit`` keys are kept (robots come and go over a long run)."""

    def __init__(self, swarm: str, kind: str, limit: int = 4096) -> None:
        self.swarm, self.kind, self.limit = swarm, kind, limit
        self._ids: dict[str, int | None] = {}

    def __call__(self, key: str) -> int | None:
        ids = self._ids
        if key not in ids:
            if len(ids) >= self.limit:
                ids.clear()
            try:
                ids[key] = parse_id(key, self.swarm, self.kind)
            except ValueError:
                ids[key] = None
        return ids[key]


def parse_alive_key(key: str, swarm: str) -> tuple[str, int]:
    """(role, id) from a liveliness key; ValueError if it is not one of this swarm's."""
    parts = str(key).split("/")
    if (
        len(parts) != 5
        or parts[0] != PREFIX
        or parts[1] != swarm
        or parts[2] != "alive"
        or parts[3] not in ROLES
    ):
        raise ValueError(f"not a liveliness key of swarm {swarm!r}: {key!r}")
    return parts[3], _parse_int_chunk(parts[4])
