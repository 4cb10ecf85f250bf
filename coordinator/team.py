"""Who may be a team member: the ids the coordinator expects, and the rest counted.

Pure (no I/O, no Zenoh). Anyone who reaches the router can declare a liveliness token or
publish poses for any id (issue 21: a token and poses for id 40 made the status read 7/7,
and 2930 phantom ids ended in trajectories.csv, ``team_changes`` and ``lost_processes``).
The launcher knows the team: ids 0..N-1 (``covswarm run --agents N``; every host of a
multi-host run uses the same N). :class:`Roster` admits only those ids, and of poses only
those of a robot whose agent has held a token at some point (before that it is no team
member yet; recording starts when the team is up, so a real robot is never cut). Anything
else is *unexpected*: counted per kind and reported (the first ids seen, and how many
distinct), never recorded as a team member.

In open mode an attacker can still forge an expected id; only secure mode's access
control (issue 21, item 1) stops that.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

# Kinds of input a Roster judges ("token_agent", "token_robot", ... per role).
KINDS = ("token_agent", "token_robot", "token_other", "pose", "state")
REPORTED_IDS = 32  # unexpected ids listed in the summary (the first seen)
MAX_TRACKED_IDS = 4096  # distinct unexpected ids counted exactly; beyond, "at least"


class Roster:
    """The expected team ``expected`` (robot ids) and what came from anyone else."""

    def __init__(self, expected: Iterable[int]) -> None:
        self.expected = frozenset(int(i) for i in expected)
        if not self.expected:
            raise ValueError("Roster: the expected team is empty")
        self.counts: dict[str, int] = dict.fromkeys(KINDS, 0)
        self._ids: dict[int, None] = {}  # distinct unexpected ids, in order of arrival
        self.confirmed: set[int] = set()  # expected ids whose agent has held a token

    @classmethod
    def of_size(cls, agents: int) -> Roster:
        """The team of ``covswarm run --agents N``: ids 0..N-1."""
        if agents < 1:
            raise ValueError(f"Roster: team of {agents} agents")
        return cls(range(agents))

    def _unexpected(self, kind: str, rid: int) -> bool:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if rid not in self._ids and len(self._ids) < MAX_TRACKED_IDS:
            self._ids[rid] = None
        return False

    def admit_token(self, role: str, rid: int) -> bool:
        """Whether a liveliness change of ``role``'s token for ``rid`` concerns the team
        (call before Liveness.update: a refused one changes no count, no team and no
        lost-process record). An agent token's appearance confirms its robot's poses."""
        if rid not in self.expected:
            kind = f"token_{role}" if f"token_{role}" in self.counts else "token_other"
            return self._unexpected(kind, rid)
        if role == "agent":
            self.confirmed.add(rid)
        return True

    def admit_pose(self, rid: int) -> bool:
        """Whether a pose of robot ``rid`` may enter e_a and the records: an expected id
        whose agent has held a token."""
        if rid in self.confirmed:
            return True
        return self._unexpected("pose", rid)

    def admit_state(self, rid: int) -> bool:
        """Whether an AgentState (its stats) of ``rid`` counts: an expected id."""
        return rid in self.expected or self._unexpected("state", rid)

    def admit_observations(self, observations: np.ndarray) -> np.ndarray:
        """The rows of ``observations`` ((n, k) array, robot id in column 0: the
        coordinator's recorded poses) that admit_pose admits, in order."""
        rows = np.asarray(observations)
        keep = np.array([self.admit_pose(int(rid)) for rid in rows[:, 0]], dtype=bool)
        return rows[keep]

    def members(self, alive: Mapping[str, set[int]]) -> frozenset[int]:
        """The team now: expected ids whose robot and agent both hold a token
        (monitor.team_of, restricted to the roster)."""
        return frozenset(alive.get("robot", set()) & alive.get("agent", set()) & self.expected)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> dict[str, Any]:
        """summary.json's ``unexpected``: counts per kind, the first REPORTED_IDS ids, and
        how many distinct ids (a lower bound past MAX_TRACKED_IDS)."""
        ids = list(self._ids)
        return {
            "expected": len(self.expected),
            "counts": {k: n for k, n in self.counts.items() if n},
            "total": self.total,
            "distinct_ids": len(ids),
            "distinct_ids_at_least": len(ids) >= MAX_TRACKED_IDS,
            "first_ids": ids[:REPORTED_IDS],
        }
