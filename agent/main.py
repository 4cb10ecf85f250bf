"""``covswarm agent``: the brain of one robot (or several), as its own process.

Each agent knows only its neighbourhood: what it receives per second depends on how many
robots are near it, never on the team size.

Neighbour discovery
-------------------
- **Own robot**: subscribes to ``robot/<me>/pose``; publishes ``robot/<me>/cmd``.
- **Domain**: subscribes to the broadcast ``domain`` and extrapolates it between messages
  (vertices + velocities * time since its stamp, for at most ``--max-extrapolation`` s; after
  that the domain holds still and its velocities count as zero).
- **Beacons (bootstrap)**: every ``--beacon-period`` (10 s), and at most 1 s after the
  last one whenever another agent's liveliness token appears (a newcomer, or a team
  starting) or a neighbour's AgentState keeps leaving it out, the agent publishes a Beacon
  on ``beacon/<tx>/<ty>/<me>``, (tx, ty) = floor(position / tile_size) with the swarm's
  tile size from the Domain broadcast (none before the first Domain), and subscribes to
  the (2r+1)^2 tiles around its own with ``beacon/<tx>/<ty>/*`` selectors, re-declared
  when it changes tile. r starts at 1 (3x3 tiles) and grows, up to ``--max-tile-radius``,
  while its cell is too large for the tiles to hold every robot that could cut it (a
  robot farther than twice the cell radius cannot; see :func:`cell_reach`). A robot known
  only from its beacon is a candidate at the beacon's position while that beacon is the
  newest news of it.
- **Two-hop set**: the agent publishes AgentState at the control rate, at most every
  ``--state-period`` (0.1 s: at 10 Hz every step, at 30 Hz every third): its robot's
  position and velocity, its current Voronoi neighbour ids, and the positions and
  velocities of those neighbours as it used them (``relay``; first-hand ones only), with
  its stats about once a second. It subscribes to the AgentStates of its one-hop
  neighbours, whose relays give it the positions of the rest of its two-hop set, plus
  those of any two-hop robot that no fresh relay carries yet; per-id subscribers are
  declared and undeclared as the set changes and linger ``--linger`` s after an id leaves
  it, so a neighbour flickering across a Voronoi vertex does not churn subscriptions.
  Other robots' positions never come from their 20 Hz poses: one subscription and 10
  messages per second per one-hop neighbour, none per outer-ring robot, for positions
  one control period older (two when relayed).
- Positions are taken from a robot's own AgentState (or pose, for a bridge that sends
  them) while younger than ``--stale-timeout`` (receipt time, so clock skew between
  machines does not matter), else from the freshest neighbour's relay of it younger than
  that, else from its beacon while younger than ``--beacon-timeout``; older robots are
  dropped. All are dead-reckoned with the velocity they carry (what the robot's wheels
  achieve, not the unsaturated command), for at most DEAD_RECKONING_LIMIT s per hop, or
  for as long as a command stays in force when the brain is stepped late (AgentBrain.pace).
- **Faults** (docs/faults.md): a robot whose agent's or robot's liveliness token is deleted
  (``alive/*/*``, changes only) leaves the local diagram at once; an agent whose own pose is
  stale commands (0, 0) and publishes no AgentState or beacon. ``--pose-loss`` /
  ``--pose-delay`` inject seeded loss and delay of poses and AgentStates
  (:class:`PoseImpairment`).

Bad input is dropped, counted per reason (``drop_<reason>`` in AgentState.stats) and
logged rate-limited (protocol.inbound): undecodable or invalid payloads (ProtocolError
reasons), a key and message that disagree about the id, a domain that is not a convex
polygon, is older than the one held, jumps implausibly far ahead of it
(``domain_seq_jump``) or leaves ``--workspace`` (``domain_outside_workspace``), and
stamps outside the clock policy of
protocol.inbound (more than ``--max-clock-skew`` ahead of this clock, or older than the
message's timeout plus that skew).

Each step the agent calls covswarm.tvd.control.local_step on itself plus the candidates that can
matter (its two-hop set and robots within 1.25x its cell's reach, see
:meth:`AgentBrain.relevant`): the local partial Voronoi diagram of its two-hop
neighbourhood, whose cost grows with the square of its size, so beacon-only robots far
away are left out. It maps the velocity to wheel speeds with covswarm.tvd.drive.wheel_speeds and
publishes a WheelCommand. Waiting/done, no domain, or no fresh own pose give a (0, 0)
command; so does any failure of the math (the robot stops rather than crash or receive
NaN). Neighbours are computed while waiting too, so the sets are warm at the start. The
liveliness token ``alive/agent/<id>`` is declared once the agent hears its own robot.

Message rates per agent (robot poses at 20 Hz, agents at 10 Hz, k one-hop neighbours, b
robots in the beacon tiles): receives 20 (own pose) + domain rate + 10 k (states) + b / 10
(beacons) per second; sends 10 commands + 10 states + 0.1 beacon per second.

``covswarm agent --ids 0-9`` runs several brains in one process (:func:`run_agents`: one
Zenoh session, each brain with its own keys, subscriptions, claim and token);
``--time-scale`` runs on mission time slower than real time (runtime.clock.scaled).

Subscribers (liveliness included) use ring channels that the main loop polls once per
tick, so no Python callback thread exists; all decoding and math happen in the main loop.
A process subscribes once per key for all its brains that follow it and decodes each
payload once (:class:`~covswarm.agent.pack.Pack`). The decision logic
(:class:`~covswarm.agent.brain.AgentBrain`) is a sans-IO state machine, unit-tested without
Zenoh; the pack carries out its actions over :class:`~covswarm.agent.link.ZenohBus`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any

import click
import zenoh

from covswarm import protocol
from covswarm.agent.brain import AGENT_PROJECTION_DISTANCE, AgentBrain
from covswarm.agent.config import AgentProcessConfig
from covswarm.agent.decoding import MessageDecoder
from covswarm.agent.faults import delay_steps
from covswarm.agent.link import ZenohBus
from covswarm.agent.metrics import Counters
from covswarm.agent.pack import Pack, collect_less
from covswarm.protocol.keys import format_ids
from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.protocol.session import open_session, session_config
from covswarm.runtime.claims import claim_or_refuse
from covswarm.runtime.clock import StopFlag, Ticker, scaled
from covswarm.runtime.options import (
    FAULT_DELAY_MAX,
    MAX_CLOCK_SKEW_OPTION,
    MAX_RATE,
    ROUTER_HELP,
    SWARM_OPTION,
    TIME_SCALE_OPTION,
    VERBOSE_OPTION,
    connect_option,
    count_option,
    float_option,
    id_options,
    id_selection,
    kappa_option,
    law_option,
    pose_delay_option,
    pose_loss_option,
    switch_option,
)
from covswarm.tvd.drive import KHEPERA_IV, MAX_WHEEL_SPEED
from covswarm.tvd.safety import DEFAULT_MARGIN

# s after start-up before an agent that has not heard its robot or a domain says so
SILENT_AFTER = 30.0
log = logging.getLogger("covswarm.agent")
# A late brain's robot runs on its last command for at most this many control periods
# before the brain stops it (covswarm.agent.pack): a brain stepping every other period of
# an overloaded process keeps its robot moving, one that cannot step for longer stops it
# before the robot's own command timeout (0.5 s) would, at 10 Hz.
HOLD_AFTER_PERIODS = 3.0


def run_agents(
    brains: list[AgentBrain],
    swarm: str,
    config: zenoh.Config,
    rate: float,
    time_scale: float = 1.0,
    phase: float | None = None,
) -> list[Counters]:
    """Zenoh shell around ``brains``: runs until SIGINT/SIGTERM, returns their counters.

    Several brains may share this process and its one Zenoh session (``covswarm agent
    --ids``): one process costs ~80 MB and its own imports, one more brain almost nothing.
    Each brain has its own publishers, claim and liveliness token and talks to the others
    only through Zenoh; the process subscribes once per key for all the brains that follow
    it (covswarm.agent.pack.Pack: each brain gets exactly the keys it follows, as if it ran
    alone), and the brains step one after the other in one loop at ``rate`` Hz of mission
    time, each holding its robot when its turn comes after its period ended.

    Every id is claimed (runtime.claims.claim) before anything is published: an agent for
    an id that is already running refuses to start. A brain's liveliness token (what
    launcher and coordinator wait for) is declared once it hears its own robot, so "every
    agent alive" means "every agent can steer". ``time_scale``: see runtime.clock.scaled.
    ``phase``: when in the period the batch starts (runtime.clock.Ticker): the launcher
    spreads the agent processes of a machine over the period, so that their batches take
    turns on the cores rather than collide.
    """
    stop = StopFlag()
    wall_clock = scaled(time.time, time_scale)
    with open_session(config) as session:
        claims: list[zenoh.LivelinessToken] = []
        ticker = Ticker(rate, time_scale=time_scale, phase=phase)
        pack: Pack | None = None
        try:
            for brain in brains:
                claims.append(claim_or_refuse(session, swarm, "agent", brain.id))
            pack = Pack(ZenohBus(session), swarm, brains, hold_after=HOLD_AFTER_PERIODS / rate)
            collect_less()
            check_at: float | None = time.monotonic() + SILENT_AFTER
            while not stop.is_set():
                ticker.wait(stop)
                pack.tick(ticker.now, wall_clock, ticker.deadline)
                if check_at is not None and time.monotonic() >= check_at:
                    check_at = None
                    if (silence := unheard(brains, swarm)) is not None:
                        log.warning(silence)
        finally:
            if pack is not None:  # stop the robots at once rather than after their timeout
                pack.stop(wall_clock())
                for token in pack.tokens.values():
                    token.undeclare()
            for token in claims:
                token.undeclare()
        for brain in brains:
            log.info(
                "agent %d stopping: %s, dropped %s, stats %s",
                brain.id,
                brain.counters,
                brain.drops.summary(),
                brain.stats(),
            )
        log.info("%d ticks, %d overruns", ticker.ticks, ticker.overruns)
    return [brain.counters for brain in brains]


def unheard(brains: Sequence[AgentBrain], swarm: str) -> str | None:
    """What none of ``brains`` has heard yet (its robot's pose, a domain), said with the
    likely reason, or None when each heard both: the one clue a process started under
    another swarm's name (a forgotten --swarm is "default") gets, since it hears nothing."""
    ids = format_ids(sorted(b.id for b in brains))
    missing = [
        what
        for what, heard in (
            ("its robot's pose", any(b.pose is not None for b in brains)),
            ("a domain from the coordinator", any(b.domain is not None for b in brains)),
        )
        if not heard
    ]
    if not missing:
        return None
    return (
        f"agent {ids} of swarm {swarm!r} has not heard {' nor '.join(missing)} in "
        f"{SILENT_AFTER:g} s: is that process running, and is {swarm!r} its swarm's name "
        "(--swarm)?"
    )


@click.command("agent")
@id_options("Several brains in this process instead, e.g. 0-9 (one session).")
@connect_option(ROUTER_HELP)
@SWARM_OPTION
@float_option("--rate", low=0.5, high=MAX_RATE, default=10.0, help="Control periods per second.")
@float_option(
    "--tick-phase",
    low=0.0,
    high=1.0,
    high_open=True,
    help="Start the control periods at this fraction of a period of the machine's "
    "monotonic clock (default: one period after start).",
)
@TIME_SCALE_OPTION
@kappa_option("Gain; default: the kappa broadcast with the domain.")
@switch_option("feedforward", "Use the dc/dt term (--no-feedforward: drop it, an ablation).")
@law_option("da: domain-motion feedforward (docs/tracking.md); d1: the paper's TVD-D1.")
@float_option(
    "--stale-timeout",
    low=0.01,
    default=1.0,
    help="A neighbour's own pose or AgentState, or a relay of it, older than this (s) leaves "
    "the local diagram.",
)
@float_option(
    "--state-period",
    low=0.0,
    default=0.1,
    help="Least time between two AgentStates, s (0: one every control step; must be below "
    "--stale-timeout). A faster control loop keeps its neighbours' news at this period.",
)
@float_option(
    "--beacon-period",
    low=0.05,
    default=10.0,
    help="s between two routine beacons on our tile (how robots not yet neighbours find us).",
)
@float_option("--beacon-timeout", low=0.1, default=25.0, help="s a beacon heard stays usable.")
@click.option(
    "--max-tile-radius",
    type=click.IntRange(1, 10),
    default=3,
    show_default=True,
    help="Beacon tiles followed around our own, at most this many in each direction.",
)
@float_option(
    "--max-extrapolation",
    low=0.0,
    default=1.0,
    help="S (and its density) is moved along its broadcast velocities for at most this "
    "long (s) after its stamp, then held still.",
)
@float_option(
    "--linger",
    low=0.0,
    default=0.5,
    help="s a robot's AgentState stays followed after it left our two-hop set.",
)
@MAX_CLOCK_SKEW_OPTION
@float_option(
    "--max-wheel-speed",
    low=0.0,
    low_open=True,
    default=MAX_WHEEL_SPEED,
    help="Rim speed limit (m/s) the commands are saturated to.",
)
@pose_loss_option(
    "Fault injection: drop this fraction of the positions received (the robot's poses and "
    "the neighbours' AgentStates)."
)
@pose_delay_option("Fault injection: deliver those positions this many s late.")
@count_option("--pose-seed", default=0, low=0, help="Seed of the pose drops.")
@switch_option(
    "prediction",
    "--no-prediction: control from the last pose as received, not predicted to the command's time.",
)
@float_option(
    "--cmd-timeout",
    low=0.01,
    default=0.5,
    help="The robot's command timeout, s (what the prediction assumes it does meanwhile).",
)
@float_option(
    "--command-latency",
    low=0.0,
    high=0.5,
    default=0.0,
    help="Known time from a command's stamp to the wheels acting on it, s: the agent "
    "looks that far ahead at its robot, S and the others; at most the measured one "
    "(docs/real-robots.md).",
)
@float_option(
    "--projection-distance",
    low=0.0,
    low_open=True,
    default=AGENT_PROJECTION_DISTANCE,
    help="Near-identity mapping's point ahead of the axle, m (covswarm.agent.brain).",
)
@switch_option("safety", "Collision-avoidance filter (--no-safety: none, to compare).")
@float_option(
    "--safety-margin",
    low=0.0,
    default=DEFAULT_MARGIN,
    help="Distance kept between two robots' bodies, m.",
)
@float_option(
    "--body-diameter",
    low=0.0,
    low_open=True,
    default=KHEPERA_IV.body_diameter,
    help="This robot's body diameter, m (the safety filter's disks).",
)
@click.option(
    "--workspace",
    type=float,
    nargs=4,
    default=None,
    metavar="XMIN XMAX YMIN YMAX",
    help="The scenario's workspace, m: a domain outside it is refused [no check].",
)
@float_option(
    "--fault-step-delay",
    low=0.0,
    high=FAULT_DELAY_MAX,
    default=0.0,
    help="Fault injection: every control step takes this many s more (a sleep): a starved "
    "process that holds fewer steps than asked.",
)
@SECURE_OPTION
@VERBOSE_OPTION
def agent_command(**options: Any) -> None:
    """Run the coverage-control brain of one robot, or of several (local two-hop Voronoi;
    TVD-DA by default, the paper's TVD-D1 with --law d1)."""
    run_agent_process(AgentProcessConfig(**options))


def run_agent_process(config: AgentProcessConfig) -> None:
    """The agent process ``config`` describes: its brains until SIGINT/SIGTERM."""
    logging.basicConfig(level=logging.INFO if config.verbose else logging.WARNING)
    try:
        protocol.check_swarm(config.swarm)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--swarm") from exc
    robot_ids = id_selection(config.id, config.ids)
    try:
        zenoh_config = session_config(
            list(config.connect), None, "client", secure=config.secure, role="agent", id=robot_ids
        )
    except ValueError as exc:  # clear endpoints in secured mode, incomplete secure folder
        raise click.UsageError(str(exc)) from exc
    if config.state_period >= config.stale_timeout:
        raise click.BadParameter(
            f"{config.state_period} s is not below --stale-timeout ({config.stale_timeout} s): "
            "neighbours would drop this agent between two of its AgentStates",
            param_hint="--state-period",
        )
    decoder = MessageDecoder()  # shared: the brains of a process decode each payload once
    try:
        brains = [AgentBrain(i, config.brain(), decoder) for i in robot_ids]
    except ValueError as exc:  # an empty or non-finite --workspace
        raise click.BadParameter(str(exc), param_hint="--workspace") from exc
    delay_steps(brains, config.fault_step_delay)
    with watch_expiry(config.secure, "agent", robot_ids):  # its certificate's end stops it
        run_agents(
            brains, config.swarm, zenoh_config, config.rate, config.time_scale, config.tick_phase
        )
