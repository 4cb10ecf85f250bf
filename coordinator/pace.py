"""Pacing the mission to what the team holds (issue 24, item 4): sans-IO, numpy only.

When the machine cannot step the agents at the asked control rate, a late brain skips its
period and then stops its robot (covswarm.agent.pack); if S kept moving at the script's
speed meanwhile, the team would fall behind it and e_a grow without bound. So the
coordinator slows the script down to what the team holds:

    S(t) = S_script(tau(t)),  dtau/dt = pace(t) in [PACE_FLOOR, 1],

and broadcasts the exact velocities dS/dt = S_script'(tau) * pace (the density's rates
likewise). Mission time t stays 1:1 with the wall clock (the agents extrapolate S by the
age of its stamp): the script is warped, not the clock. The mission ends when tau reaches the
script's duration.

The pace follows the fraction of the asked rate the team holds, measured from the agents'
stats (one AgentState with stats about once a second): agent i held
``(mission_steps - earlier) / (stamp - earlier stamp) / asked`` since its report of
HELD_WINDOW s before (``rate_hz / asked``, a 5 s window, until two reports of the mission
exist). Two seconds rather than one report's interval: at 10 Hz one tick more or less in a
one-second window would read as a 10 % change.
The team's figure is the SLOW_QUANTILE of its members' (the slowest tenth: the team stays
together only if its slow members keep up, but a single straggler does not freeze
everyone). A member that stops reporting keeps its last figure: a brain that is frozen,
hung or dead before its token lapses is a fault the team covers for (its robot stops on
its command timeout, docs/faults.md), not a machine that holds less; a starved brain
still reports whenever it steps, with its low rate. The pace falls at once to the team's
figure, rises by at most RISE_RATE per second, and moves only outside a dead band
(DROP_BAND, RISE_BAND: report jitter does not make S surge and stall), except that it
climbs all the way back to 1 once the team holds its rate again. A team holding
FULL of the rate holds it: a brain stepping 4 of 5 periods never holds its robot
(covswarm.agent.pack holds it after three missed periods in a row) and its gain is
sampled for the period it holds, so the script need not wait for it.

A deploy hold (``deploying``): the script waits at tau = 0, pace 0, from the mission's
start until the coordinator releases it (:func:`deploy_release`: the team's e_a at or below
a target, or a timeout), so that the team first spreads over S(0) to its CVT, as a team is
deployed before an operator moves it. The hold may run at a gain of its own
(--deploy-kappa), reached from the mission's over DEPLOY_GAIN_RAMP s when higher
(:func:`hold_gain`). Once it may end, S stays still DEPLOY_ALIGN s more while the Domain
announces the motion S will start with (:meth:`Pace.align`,
:func:`broadcast_motion`), so that the robots, standing at their centroids facing wherever
their last moves left them, turn in place to face it (covswarm.agent.brain), as they do
before the mission. S then starts gently: its pace rises from 0 to 1 over DEPLOY_RAMP s
(:func:`ramp_pace`; lower if the team holds less); pacing applies from then on. It is the
one pause at pace 0.

PACE_FLOOR rather than a pause at pace 0 for an overloaded team: a mission on a machine
that holds nothing still ends (after at most 1 / PACE_FLOOR its duration). Not higher: a
team that holds less than the floor falls behind S for good. At 0.05, 1000 robots on two
slow cores held 0.2 Hz (0.02 of 10 Hz; 30 Nov 2026 18:08 UTC) and e_a rose from 0.7 to
13 m; in covswarm.deploy.netsim (circle-400, brains every 4-6 s, 60 s) e_a ended at 0.46 m
and rising with S at 0.05, 0.083 m and falling at 0.02 (the team's figure then).

tau between two ticks is linear in t with the slope broadcast at the first (what the
agents extrapolate), so :meth:`Pace.script_time` gives S at any past mission time exactly
as broadcast (an e_a sample placed at its poses' time).
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from covswarm.coordinator.monitor import DONE, RUNNING
from covswarm.protocol.messages import MAX_KAPPA
from covswarm.tvd.density import Density

PACE_FLOOR = 0.01  # slowest pace: the mission lasts at most 100x its script
FULL = 0.8  # a team that holds this fraction of the asked rate holds it (module docstring)
DROP_BAND = 0.03  # the pace falls only to a target this far below it ...
RISE_BAND = 0.05  # ... and rises only towards one this far above it
# Below this pace both bands shrink with it: a team held at the floor, 0.01, that holds 0.024
# of its rate would otherwise rise only at 0.06 (1000 robots on two slow cores: 0.244 Hz
# held, the script at 0.01x for 345 s, 30 Nov 2026 18:48 UTC).
BAND_PACE = 0.2
RISE_RATE = 0.1  # pace per s of mission time: from 0.4 back to 1 in 6 s
SLOW_QUANTILE = 0.1  # the team's figure: the slowest tenth of its members
HELD_WINDOW = 2.0  # s of an agent's reports its held rate is measured over
# s: after a deploy hold S starts gently, its pace rising from 0 to 1 over this long, so
# that robots standing still, facing anywhere, turn to its motion before it is fast
DEPLOY_RAMP = 2.0
# s: once the deploy hold may end, S stays still this long more, announcing its start
# motion, for the robots to turn to face it: at release they faced wherever their last
# moves left them, and e_a rose from 0.05 to 0.16 m while they turned (300 robots,
# circle-400, covswarm sim, seeds 0 and 1), 0.05 when they faced S's motion. An agent's
# turn in place closes period / command timeout of its heading error a period (0.2 at 10
# Hz): 89 % of it in 1 s.
DEPLOY_ALIGN = 1.0
# s: a deploy hold at a gain of its own above the mission's (--deploy-kappa) starts at the
# mission's and ramps up to it over this long (hold_gain): robots standing far from their
# centroids at the start, at gain 8 at once, saturated their wheels (2.6-3.6 robot-s in
# 300 live robots) and brought a pair within a body 0.3-0.7 s in, in two runs of three.
DEPLOY_GAIN_RAMP = 1.0


def held_fraction(
    stats: Mapping[str, float], stamp: float, previous: tuple[float, float] | None, asked: float
) -> float:
    """The fraction of ``asked`` Hz an agent held (>= 0, not capped): its mission steps per
    s since ``previous`` (stamp, mission_steps of an earlier report, None: none) when both
    reports are of the mission and in order, else its reported ``rate_hz`` (0 without)."""
    steps = float(stats.get("mission_steps", 0.0))
    if previous is not None and previous[1] > 0 and steps >= previous[1] and stamp > previous[0]:
        return (steps - previous[1]) / (stamp - previous[0]) / asked
    rate = float(stats.get("rate_hz", 0.0))
    return rate / asked if math.isfinite(rate) else 0.0


def team_target(fractions: Iterable[float]) -> float:
    """The pace the team can hold, from its members' held fractions: 1 without any, else
    their SLOW_QUANTILE, 1 from FULL up, at least PACE_FLOOR."""
    values = np.fromiter(fractions, dtype=float)
    if values.size == 0:
        return 1.0
    slow = float(np.quantile(np.nan_to_num(values, nan=0.0), SLOW_QUANTILE))
    return 1.0 if slow >= FULL else max(PACE_FLOOR, slow)


def next_pace(pace: float, target: float, dt: float) -> float:
    """The pace after ``dt`` s towards ``target``: down at once, up by RISE_RATE per s,
    unchanged within the dead band (but all the way back to 1 once the rate is held); below
    BAND_PACE the band is that fraction of its width."""
    scale = min(1.0, pace / BAND_PACE)
    if target < pace - DROP_BAND * scale:
        return target
    if target > pace + RISE_BAND * scale or target == 1.0:
        return min(target, pace + RISE_RATE * max(dt, 0.0))
    return pace


def deploy_release(
    t: float, error: tuple[float, float] | None, target: float, timeout: float
) -> str | None:
    """Why the deploy hold ends at mission time ``t`` (s), or None while it holds:
    "converged" once the latest e_a sample of the hold, ``error`` = (its mission time s,
    e_a m; None: none yet), is at or below ``target`` m; else "timed out" once ``t`` >=
    ``timeout``."""
    if error is not None and error[1] <= target:
        return "converged"
    return "timed out" if t >= timeout else None


def aligned_by(t: float, since: float) -> bool:
    """Whether S, held still from mission time ``since`` (s) for the robots to face its
    start, has been so DEPLOY_ALIGN s by ``t`` (to rounding: ticks and steps add up)."""
    return t - since >= DEPLOY_ALIGN - 1e-9


def check_deploy_kappa(deploy_error: float | None, deploy_kappa: float | None) -> None:
    """ValueError for a gain of the deploy hold (1/s) without a hold, or that a Domain
    cannot carry (not positive, or above protocol.messages.MAX_KAPPA)."""
    if deploy_kappa is None:
        return
    if deploy_error is None:
        raise ValueError("--deploy-kappa is the deploy hold's gain: it needs --deploy-error")
    if not 0.0 < deploy_kappa <= MAX_KAPPA:  # NaN too; a Domain carries at most MAX_KAPPA
        raise ValueError(
            f"the deploy hold's gain must be positive and at most {MAX_KAPPA:g}, "
            f"not {deploy_kappa!r}"
        )


def gain_ramp(kappa: float, hold_kappa: float) -> float:
    """s a deploy hold's gain ``hold_kappa`` (1/s, --deploy-kappa) takes to reach from the
    mission's ``kappa``: DEPLOY_GAIN_RAMP when it is higher, else 0 (it holds from the
    start)."""
    return DEPLOY_GAIN_RAMP if hold_kappa > kappa else 0.0


def hold_gain(t: float, kappa: float, hold_kappa: float) -> float:
    """The gain (1/s) of a deploy hold at mission time ``t`` (s; it holds from t = 0):
    ``hold_kappa``, reached from ``kappa`` linearly over :func:`gain_ramp` s."""
    ramp = gain_ramp(kappa, hold_kappa)
    if ramp <= 0.0 or t >= ramp:
        return hold_kappa
    return kappa + (hold_kappa - kappa) * max(t, 0.0) / ramp


def ramp_pace(since: float) -> float:
    """The pace ``since`` s after a deploy hold ended (the end of a period that began
    then: what the period is broadcast with): linear from 0 to 1 over DEPLOY_RAMP s, at
    least PACE_FLOOR."""
    return min(1.0, max(PACE_FLOOR, since / DEPLOY_RAMP))


def broadcast_motion(
    state: str, velocities: np.ndarray, pace: float = 1.0, aligning: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """What a Domain of mission ``state`` says of S's motion: the vertex velocities (n, 2)
    m/s it broadcasts, and its start velocities (protocol.Domain.start_velocities) or None.

    ``velocities``: the script's S_script'(tau) (n, 2) m/s. Only a running S moves, at
    ``pace`` times them. While the mission waits, and at the end of a deploy hold
    (``aligning``: :meth:`Pace.align`), S holds still and announces the motion it will start
    with (None when it starts still), so that robots turn to face it beforehand
    (covswarm.agent.brain); once done it holds still and announces nothing."""
    if state == RUNNING and not aligning:
        return velocities * pace, None
    start = velocities if state != DONE and np.any(velocities) else None
    return np.zeros_like(velocities), start


def paced_density(density: Density, pace: float, t: float) -> Density:
    """``density`` (the script's phi at tau) with its rates scaled by ``pace`` and stamped
    with mission time ``t``: what an agent advances with mission time (d phi / dt)."""
    return Density(
        density.floor,
        density.means,
        density.covariances,
        density.weights,
        density.mean_rates * pace,
        density.covariance_rates * pace,
        density.weight_rates * pace,
        time=t,
    )


@dataclass
class Pace:
    """The script's clock tau(t) of one run and what it was derived from.

    ``asked``: the agents' control rate (Hz of mission time); ``enabled``: False keeps
    pace 1 (tau = t) whatever the agents hold, while still measuring it.
    """

    asked: float
    enabled: bool = True
    # Held at tau = 0 (pace 0) until :meth:`release` (the module docstring's deploy hold).
    deploying: bool = False
    pace: float = 1.0
    tau: float = 0.0
    # tau(t) at every tick of the mission: mission time, script time, pace from then on
    t_log: list[float] = field(default_factory=list)
    tau_log: list[float] = field(default_factory=list)
    pace_log: list[float] = field(default_factory=list)
    held: dict[int, float] = field(default_factory=dict)  # fraction of asked, per agent
    # per agent: (stamp, mission_steps) of its reports, the oldest HELD_WINDOW s back
    _reports: dict[int, deque[tuple[float, float]]] = field(default_factory=dict)
    # per agent: (stamp, mission_steps) of its first report of the mission and its latest
    _span: dict[int, tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=dict)
    # the deploy hold's end: mission time (s), why (deploy_release), e_a (m) then; None while
    # it holds or without one
    released: tuple[float, str, float | None] | None = None
    # when the hold could end (the same three), S then held DEPLOY_ALIGN s more (align)
    aligned_from: tuple[float, str, float | None] | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.asked) and self.asked > 0.0):
            raise ValueError(f"the asked control rate must be positive, got {self.asked!r}")
        if self.deploying:
            self.pace = 0.0

    def release(self, t: float, reason: str, error: float | None) -> None:
        """End the deploy hold at mission time ``t``: the script runs from the next
        :meth:`advance` on (``released`` then holds its time), at the pace the team holds."""
        if self.deploying:
            self.deploying = False
            self.released = (t, reason, error)

    def align(self, t: float, reason: str, error: float | None) -> None:
        """The deploy hold may end at mission time ``t`` (``reason``, e_a ``error`` m): S holds
        still DEPLOY_ALIGN s more, announcing its start motion (:attr:`aligning`); a later
        call changes nothing."""
        if self.aligned_from is None:
            self.aligned_from = (t, reason, error)

    @property
    def aligning(self) -> bool:
        """Whether the hold may end and S holds still for the robots to face its start."""
        return self.deploying and self.aligned_from is not None

    def report(self, ident: int, stats: Mapping[str, float], stamp: float) -> None:
        """Agent ``ident``'s stats, stamped ``stamp`` (its mission-scaled wall clock, s)."""
        reports = self._reports.setdefault(ident, deque())
        steps = float(stats.get("mission_steps", 0.0))
        if reports and (steps < reports[-1][1] or stamp <= reports[-1][0]):
            reports.clear()  # a restarted agent, or a report out of order
        self.held[ident] = held_fraction(stats, stamp, reports[0] if reports else None, self.asked)
        reports.append((stamp, steps))
        if steps > 0.0:
            first = self._span.get(ident, ((stamp, steps),))[0]
            self._span[ident] = (first if steps >= first[1] else (stamp, steps), (stamp, steps))
        while len(reports) > 1 and reports[1][0] <= stamp - HELD_WINDOW:
            reports.popleft()

    def target(self, team: Iterable[int]) -> float:
        """The pace ``team`` (alive members' ids) holds (:func:`team_target` of their latest
        figures; members never heard from are left out)."""
        return team_target(self.held[i] for i in team if i in self.held)

    def advance(self, t: float, team: Iterable[int], end: float = math.inf) -> float:
        """Mission time ``t``: tau advanced at the pace broadcast since the last tick (up
        to the script's ``end``), then the pace for what follows; returns tau. A ``t`` not
        after the last tick's (a mission that is done) changes nothing."""
        if self.t_log and t <= self.t_log[-1]:
            return self.tau
        if self.t_log:
            dt = t - self.t_log[-1]
            self.tau = min(self.tau + self.pace * dt, end)
            if self.deploying:
                pass  # pace 0 until released
            elif self.released is not None and (
                self.pace == 0.0 or t - self.released[0] < DEPLOY_RAMP
            ):
                if self.pace == 0.0:  # released since the last tick: S moves from this one on
                    self.released = (t, *self.released[1:])
                self.pace = self._ramp(t, dt, team)
            else:
                self.pace = next_pace(self.pace, self.target(team), dt) if self.enabled else 1.0
        elif not self.deploying:
            self.tau = min(t, end)  # the mission's first tick (0, or a resumed mission's t)
        self.t_log.append(t)
        self.tau_log.append(self.tau)
        self.pace_log.append(self.pace)
        return self.tau

    @property
    def starting(self) -> bool:
        """Whether the pace since the last tick is the deploy hold's or its ramp's (S
        starting), not the team's."""
        if self.deploying:
            return True
        return (
            self.released is not None
            and bool(self.t_log)
            and self.t_log[-1] - self.released[0] < DEPLOY_RAMP
        )

    @property
    def slowed(self) -> bool:
        """Whether S runs slower than its script because the team does not hold its rate
        (not because it is starting)."""
        return self.pace < 1.0 and not self.starting

    def _ramp(self, t: float, dt: float, team: Iterable[int]) -> float:
        """The pace from ``t`` on while S starts after the deploy hold (ramp_pace; the
        team's, if lower), ``dt`` s after the last tick (the period's length to expect)."""
        ramp = ramp_pace(t - self.released[0] + dt)
        return min(ramp, self.target(team)) if self.enabled else ramp

    def clock(self) -> ScriptClock | None:
        """Where the script's clock stands at the last tick (None before the mission)."""
        return ScriptClock(self.t_log[-1], self.tau, self.pace) if self.t_log else None

    def resume(self, clock: ScriptClock) -> None:
        """Continue the script's clock of a previous coordinator: the next :meth:`advance`
        moves tau on from ``clock.tau`` at ``clock.pace`` (what the agents extrapolated
        meanwhile), not from the mission time."""
        self.tau, self.pace = clock.tau, clock.pace
        self.deploying = clock.pace == 0.0  # the first one stopped during its deploy hold
        self.t_log, self.tau_log, self.pace_log = [clock.t], [clock.tau], [clock.pace]

    def script_time(self, t: float) -> float:
        """tau at mission time ``t`` as broadcast (linear between ticks, the last pace on)."""
        if not self.t_log:
            return t
        k = int(np.searchsorted(self.t_log, t, side="right")) - 1
        if k < 0:
            return self.tau_log[0] - (self.t_log[0] - t)
        return self.tau_log[k] + self.pace_log[k] * (t - self.t_log[k])

    def mission_time(self, tau: float) -> float:
        """The mission time at which the script reached ``tau`` (inverse of script_time on
        the mission's ticks; past the last tick at its pace)."""
        if not self.t_log or tau <= self.tau_log[0]:
            return tau if not self.t_log else self.t_log[0] - (self.tau_log[0] - tau)
        k = int(np.searchsorted(self.tau_log, tau, side="right")) - 1
        if self.pace_log[k] == 0.0:
            return math.inf  # still in the deploy hold: the script has not got there
        return self.t_log[k] + (tau - self.tau_log[k]) / self.pace_log[k]

    def summary(self, stats: Mapping[int, Mapping[str, float]], mission_t: float) -> dict:
        """summary.json's "pace": the rate asked and held, what was missed, the pace.

        ``stats``: every agent's latest stats; ``mission_t``: the mission's length, s.
        held_rate_hz: mission steps per s of mission, mean (min) over the agents that
        report them: between an agent's first and latest reports of the mission (stats
        come about once a second, so its latest is up to a second older than the end),
        over the whole mission for one that reported only once; periods_missed: 1 - held /
        asked (the team's mean); late_held: the agents' mean share of periods skipped by a
        late turn; missed_deadline: their mean share of commands sent after their period;
        pace_min, pace_mean: over the script's part of the mission, after a deploy hold
        ("deploy": its length hold_s, released_because (None: it held to the end), e_a
        then, m, and aligned_s: how long of it S held for the robots to face its start).
        """
        held = []
        for ident, s in stats.items():
            span = self._span.get(ident)
            if span is not None and span[1][0] > span[0][0]:
                (t0, steps0), (t1, steps1) = span
                held.append((steps1 - steps0) / (t1 - t0))
            elif "mission_steps" in s and mission_t > 0.0:
                held.append(float(s["mission_steps"]) / mission_t)

        def mean(name: str) -> float | None:
            values = [float(s[name]) for s in stats.values() if name in s]
            return float(np.mean(values)) if values else None

        # The script's part of the mission: after the deploy hold, if any (deploy key).
        hold = self.released[0] if self.released else (mission_t if self.deploying else 0.0)
        paces = np.array([p for t, p in zip(self.t_log, self.pace_log, strict=True) if t >= hold])
        paces = paces if paces.size else np.ones(1)
        reached = self.tau_log[-1] if self.tau_log else 0.0
        scripted = mission_t - hold
        deploy = {}
        if self.released or self.deploying:
            why, error = self.released[1:] if self.released else (None, None)
            aligned = 0.0 if self.aligned_from is None else hold - self.aligned_from[0]
            deploy = {
                "deploy": {
                    "hold_s": hold,
                    "released_because": why,
                    "error_at_release": error,
                    "aligned_s": aligned,
                }
            }
        return {
            "enabled": self.enabled,
            "asked_rate_hz": self.asked,
            "held_rate_hz": float(np.mean(held)) if held else None,
            "held_rate_hz_min": min(held) if held else None,
            "periods_missed": max(0.0, 1.0 - float(np.mean(held)) / self.asked) if held else None,
            "late_held": mean("late_held"),
            "missed_deadline": mean("missed_deadline"),
            "pace_min": float(paces.min()),
            "pace_mean": reached / scripted if scripted > 0.0 else 1.0,
            "script_time": reached,
            "mission_time": mission_t,
            **deploy,
        }


@dataclass(frozen=True)
class ScriptClock:
    """Where the script's clock stood: at mission time ``t`` (s) the script was at ``tau``
    (s) and ran at ``pace``. The coordinator records it for --resume, so that a restarted
    one continues the script where the first left it (:meth:`Pace.resume`)."""

    t: float
    tau: float
    pace: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.t) and math.isfinite(self.tau) and self.tau >= 0.0):
            raise ValueError(f"a script clock needs finite times, got {self.t!r}, {self.tau!r}")
        held = self.pace == 0.0 and self.tau == 0.0  # a deploy hold (Pace.deploying)
        if not (held or PACE_FLOOR <= self.pace <= 1.0):
            raise ValueError(
                f"a pace must be in [{PACE_FLOOR}, 1] (0 only at script time 0), "
                f"got {self.pace!r} at {self.tau!r}"
            )

    def to_json(self, swarm: str) -> str:
        return json.dumps({"swarm": swarm, "t": self.t, "script_t": self.tau, "pace": self.pace})

    @classmethod
    def from_json(cls, text: str, swarm: str) -> ScriptClock:
        """The clock recorded in ``text`` for ``swarm`` (ValueError if malformed, another
        swarm's, or out of range)."""
        try:
            data = json.loads(text)
            ours = data.get("swarm") == swarm
            values = float(data["t"]), float(data["script_t"]), float(data["pace"])
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a script clock: {exc!r}") from None
        if not ours:
            raise ValueError(f"not a script clock of swarm {swarm!r}")
        return cls(*values)


def pace_sentence(pace: Mapping[str, Any]) -> str:
    """summary.json's "pace" in plain words, for the coordinator's log and the launcher."""
    asked, held = pace["asked_rate_hz"], pace.get("held_rate_hz")
    if held is None:
        rate = f"the agents reported no rate (asked {asked:g} Hz)"
    else:
        rate = f"the machine held {held:.3g} Hz of {asked:g} asked"
        missed = [f"{pace['periods_missed']:.0%} of periods missed"]
        if pace.get("late_held"):
            missed.append(f"{pace['late_held']:.0%} skipped by late brains")
        rate += f" ({', '.join(missed)})"
    ran = (
        f"the mission ran at {pace['pace_mean']:.2f}x (slowest {pace['pace_min']:.2f}x): "
        f"{pace['script_time']:.1f} s of script in {pace['mission_time']:.1f} s"
    )
    if not pace["enabled"]:
        ran = f"pacing off: {ran}"
    if (deploy := pace.get("deploy")) is not None:
        why = deploy["released_because"] or "never released"
        ran = f"{ran}, after a deploy hold of {deploy['hold_s']:.1f} s ({why})"
    return f"{rate}; {ran}"
