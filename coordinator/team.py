"""Who may be a team member: the ids the coordinator expects, and the rest counted.

Pure (no I/O, no Zenoh). Anyone who reaches the router can declare a liveliness token or
publish poses for any id (issue 21: a token and poses for id 40 made the status read 7/7,
and 2930 phantom ids ended in trajectories.csv, ``team_changes`` and ``lost_processes``).
The launcher knows the team: ids 0..N-1 (``covswarm run --agents N``; every host of a
multi-host run uses the same N). :class:`Roster` admits only those ids, and of poses only
those of a robot whose agent has held a token at some point (before that it is no team
member yet; recording starts when the team is up, so a real robot is never cut). A robot
that joins later under another id (a newcomer: ``covswarm robot`` and ``covswarm agent``
started by hand) is admitted once its robot and its agent both hold their tokens and an
agent of the team names it as a Voronoi neighbour in its AgentState: the team's own
brains have found it where it says it is, which forged tokens, poses and states alone do
not achieve. Anything else is *unexpected*: counted per kind
and reported (the first ids seen, and how many distinct), never recorded as a team
member.

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
        self.confirmed: set[int] = set()  # admitted ids whose agent has held a token
        self.newcomers: set[int] = set()  # ids beyond the expected ones, admitted later
        # expected | newcomers, kept up to date: asked of every AgentState (10 000 a second
        # at 1000 robots), where building the union anew took a third of its handling.
        self._admitted = self.expected
        # Unexpected ids: the roles whose token each holds now, and whether an agent of the
        # team named it as a neighbour; and what each was counted as (undone when admitted).
        self._held: dict[int, set[str]] = {}
        self._vouched: set[int] = set()
        self._counted: dict[int, list[str]] = {}
        self._promoted: list[tuple[str, int]] = []

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
        if rid in self._held and kind != "pose":
            self._counted.setdefault(rid, []).append(kind)
        return False

    @property
    def admitted(self) -> frozenset[int]:
        """The ids that may be team members: the expected ones and admitted newcomers."""
        return self._admitted

    def admit_token(self, role: str, rid: int, alive: bool = True) -> bool:
        """Whether a liveliness change of ``role``'s token for ``rid`` (appeared when
        ``alive``) concerns the team (call before Liveness.update: a refused one changes no
        count, no team and no lost-process record). An agent token's appearance confirms
        its robot's poses. A newcomer admitted by it: :meth:`take_admitted`."""
        if rid not in self._admitted:
            if len(self._held) < MAX_TRACKED_IDS or rid in self._held:
                held = self._held.setdefault(rid, set())
                (held.add if alive else held.discard)(role)
            kind = f"token_{role}" if f"token_{role}" in self.counts else "token_other"
            self._unexpected(kind, rid)
            self._admit_newcomer(rid)
            return False
        if role == "agent" and alive:
            self.confirmed.add(rid)
        return True

    def _admit_newcomer(self, rid: int) -> bool:
        """Admit ``rid`` if its tokens are held and it was vouched for; whether it was."""
        if {"agent", "robot"} <= self._held.get(rid, set()) and rid in self._vouched:
            self.newcomers.add(rid)
            self._admitted = self.expected | self.newcomers
            self.confirmed.add(rid)
            for kind in self._counted.pop(rid, []):  # not unexpected after all
                self.counts[kind] -= 1
            self._ids.pop(rid, None)
            self._held.pop(rid)
            self._vouched.discard(rid)
            self._promoted += [("robot", rid), ("agent", rid)]
            return True
        return False

    def take_admitted(self) -> list[tuple[str, int]]:
        """The (role, id) tokens, alive now, of the newcomers admitted since the last call:
        the caller enters them in its Liveness (their tokens were refused until then)."""
        promoted, self._promoted = self._promoted, []
        return promoted

    def admit_pose(self, rid: int) -> bool:
        """Whether a pose of robot ``rid`` may enter e_a and the records: an expected id
        whose agent has held a token."""
        if rid in self.confirmed:
            return True
        return self._unexpected("pose", rid)

    def admit_state(self, rid: int) -> bool:
        """Whether an AgentState (its stats) of ``rid`` counts: an admitted id."""
        return rid in self._admitted or self._unexpected("state", rid)

    def vouch(self, rid: int, neighbors: Iterable[int]) -> bool:
        """Agent ``rid``'s AgentState names ``neighbors``: if ``rid`` is admitted, each of
        them that holds tokens is vouched for (see :meth:`admit_token`). Whether a newcomer
        was admitted (:meth:`take_admitted`)."""
        admitted = False
        if not self._held or rid not in self._admitted:  # no unexpected token: nobody to vouch for
            return admitted
        for other in neighbors:
            if other in self._held:
                self._vouched.add(other)
                admitted |= self._admit_newcomer(other)
        return admitted

    def admit_observations(self, observations: np.ndarray) -> np.ndarray:
        """The rows of ``observations`` ((n, k) array, robot id in column 0: the
        coordinator's recorded poses) that admit_pose admits, in order."""
        rows = np.asarray(observations)
        keep = np.array([self.admit_pose(int(rid)) for rid in rows[:, 0]], dtype=bool)
        return rows[keep]

    def members(self, alive: Mapping[str, set[int]]) -> frozenset[int]:
        """The team now: admitted ids whose robot and agent both hold a token
        (monitor.team_of, restricted to the roster)."""
        return frozenset(alive.get("robot", set()) & alive.get("agent", set()) & self._admitted)

    def stranded(self, alive: Mapping[str, set[int]]) -> frozenset[int]:
        """Admitted ids whose robot holds its token and whose agent does not: a robot
        stopped by its command timeout that no brain moves, which the agents take as a
        still generator of their diagrams (covswarm.agent.brain.AgentBrain.stranded)."""
        return frozenset((alive.get("robot", set()) - alive.get("agent", set())) & self._admitted)

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
