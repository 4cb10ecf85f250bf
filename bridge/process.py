"""``covswarm bridge ros2``: ROS 2 robots take simulated robots' places, over rmw_zenoh.

The thin Zenoh shell around :class:`covswarm.bridge.brain.RobotBrain` (one per robot id) and
:class:`covswarm.bridge.mission_view.MissionView`. One Zenoh session, a client of the router
that both sides reach (``rmw_zenohd`` listens on tcp/7447), carries both worlds:

- covswarm side, per id, exactly what ``covswarm robot`` does: a claim on the id (a second
  bridge or simulated robot with the same id refuses to start), a subscriber on
  ``robot/<id>/cmd``, a publisher on ``robot/<id>/pose`` and the liveliness token
  ``alive/robot/<id>``, held while the robot's ROS 2 pose is fresh;
- ROS 2 side, one node (``--node-name``) with, per id, a ``cmd_vel`` publisher (Twist or
  TwistStamped, each sample with its rmw_zenoh attachment) and a pose subscription, each
  announced by its liveliness token so that ``ros2 node list`` / ``ros2 topic list`` see
  them; with ``--publish-state``, publishers of S(t) (PolygonStamped), the robots' poses
  (PoseArray) and e_a (Float64) under ``--state-namespace``.

On SIGINT/SIGTERM every robot that was commanded gets a zero Twist before the bridge exits;
a bridge killed outright leaves that to the robots' own command timeout.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import click
import zenoh

from covswarm import protocol
from covswarm.bridge import cdr
from covswarm.bridge.brain import STAMP_SOURCES, RobotBrain
from covswarm.bridge.mission_view import MissionView
from covswarm.bridge.rmw_zenoh import (
    PUBLISHER,
    SUBSCRIPTION,
    SampleCounter,
    check_domain_id,
    check_topic,
    endpoint_token_key,
    entity_gid,
    node_token_key,
    qos_string,
    topic_key,
    topic_selector,
)
from covswarm.protocol.inbound import MAX_CLOCK_SKEW
from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.protocol.session import open_session, session_config
from covswarm.runtime.claims import claim_or_refuse
from covswarm.runtime.clock import StopFlag, Ticker
from covswarm.runtime.options import (
    MAX_CLOCK_SKEW_OPTION,
    MAX_RATE,
    connect_option,
    float_option,
    refuse_unused,
)
from covswarm.tvd.drive import KHEPERA_IV

log = logging.getLogger("covswarm.bridge")
# s after start-up before the bridge says which robots have sent no pose at all
SILENT_AFTER = 10.0

QOS = qos_string(reliable=True, depth=10)  # rclcpp's default for publishers and subscriptions
STATE_RATE = 10.0  # Hz of the --publish-state topics
TWIST_FRAME = "base_link"  # TwistStamped: velocities in the robot's own frame


@dataclass(frozen=True)
class Ros2Options:
    """Where and how the ROS 2 side lives (see the command's options)."""

    domain_id: int = 0
    cmd_topic: str = "/robot{id}/cmd_vel"
    cmd_type: str = cdr.TWIST
    pose_topic: str = "/robot{id}/pose"
    pose_type: str = cdr.POSE_STAMPED
    node_name: str = "covswarm_bridge"
    frame: str = "map"
    publish_state: bool = False
    state_namespace: str = "/covswarm"


def robot_topic(template: str, robot_id: int) -> str:
    """``template`` with ``{id}`` replaced by the robot id, checked as a ROS 2 name."""
    if "{id}" not in template:
        raise ValueError(f"topic template {template!r} must contain {{id}}")
    return check_topic(template.replace("{id}", str(robot_id)))


class Ros2Node:
    """The bridge's ROS 2 node on one Zenoh session: tokens and publishers with attachments."""

    def __init__(self, session: zenoh.Session, options: Ros2Options) -> None:
        self.session, self.options = session, options
        self.zid = str(session.zid())
        self.tokens = [
            session.liveliness().declare_token(
                node_token_key(options.domain_id, self.zid, 0, options.node_name)
            )
        ]
        self._next_entity = 1

    def _announce(self, kind: str, topic: str, ros_type: str) -> str:
        key = endpoint_token_key(
            self.options.domain_id, self.zid, 0, self._next_entity, kind,
            self.options.node_name, topic, ros_type, QOS,
        )  # fmt: skip
        self._next_entity += 1
        self.tokens.append(self.session.liveliness().declare_token(key))
        return key

    def publisher(self, topic: str, ros_type: str) -> Ros2Publisher:
        token = self._announce(PUBLISHER, topic, ros_type)
        publisher = self.session.declare_publisher(
            topic_key(self.options.domain_id, topic, ros_type)
        )
        return Ros2Publisher(publisher, SampleCounter(entity_gid(token)))

    def subscriber(self, topic: str, ros_type: str, depth: int = 32) -> zenoh.Subscriber:
        self._announce(SUBSCRIPTION, topic, ros_type)
        selector = topic_selector(self.options.domain_id, topic, ros_type)
        return self.session.declare_subscriber(selector, zenoh.handlers.RingChannel(depth))


@dataclass
class Ros2Publisher:
    publisher: zenoh.Publisher
    counter: SampleCounter

    def put(self, payload: bytes) -> None:
        self.publisher.put(payload, attachment=self.counter.next(time.time_ns()))


def _encode_twist(options: Ros2Options, twist: tuple[float, float], wall: float) -> bytes:
    if options.cmd_type == cdr.TWIST_STAMPED:
        return cdr.encode_twist_stamped(*twist, wall, TWIST_FRAME)
    return cdr.encode_twist(*twist)


def run_bridge(
    brains: list[RobotBrain], swarm: str, config: zenoh.Config, options: Ros2Options, rate: float
) -> None:
    """Run until SIGINT/SIGTERM; logs each robot's counters and drops at exit."""
    stop = StopFlag()
    with open_session(config) as session:
        claims = [claim_or_refuse(session, swarm, "robot", brain.id) for brain in brains]
        node = Ros2Node(session, options)
        wires = []
        for brain in brains:
            wires.append(
                (
                    brain,
                    session.declare_subscriber(
                        protocol.cmd_key(swarm, brain.id), zenoh.handlers.RingChannel(16)
                    ),
                    node.publisher(robot_topic(options.cmd_topic, brain.id), options.cmd_type),
                    node.subscriber(robot_topic(options.pose_topic, brain.id), options.pose_type),
                    session.declare_publisher(
                        protocol.pose_key(swarm, brain.id),
                        congestion_control=zenoh.CongestionControl.DROP,
                    ),
                )
            )
        view = StatePublisher(session, node, swarm, options) if options.publish_state else None
        alive: dict[int, zenoh.LivelinessToken] = {}
        ticker = Ticker(rate)
        seq = 0
        log.info("bridge for robots %s of swarm %s ready", [brain.id for brain in brains], swarm)
        check_at: float | None = time.monotonic() + SILENT_AFTER
        try:
            while not stop.is_set():
                now = ticker.wait(stop)
                if check_at is not None and time.monotonic() >= check_at:
                    check_at = None
                    for line in unheard_robots(brains, options):
                        log.warning(line)
                wall = time.time()
                for brain, commands, cmd_vel, poses, pose_out in wires:
                    while (sample := commands.try_recv()) is not None:
                        brain.on_command(sample.payload.to_bytes(), now, wall)
                    if (twist := brain.twist(now)) is not None:
                        cmd_vel.put(_encode_twist(options, twist, wall))
                    while (sample := poses.try_recv()) is not None:
                        attachment = sample.attachment
                        brain.on_pose(
                            sample.payload.to_bytes(),
                            None if attachment is None else attachment.to_bytes(),
                            now,
                            wall,
                        )
                    if (pose := brain.take_pose(seq)) is not None:
                        pose_out.put(pose.encode())
                    _hold_token(session, swarm, brain, now, alive)
                seq += 1
                if view is not None:
                    view.tick(now, wall)
        finally:
            for brain, _, cmd_vel, _, _ in wires:
                if brain.commands:  # leave no robot driving on the last command
                    cmd_vel.put(_encode_twist(options, (0.0, 0.0), time.time()))
            for token in [*alive.values(), *claims, *node.tokens]:
                token.undeclare()
    for brain in brains:
        # A robot that never published, or whose data was dropped, is said without --verbose.
        level = logging.WARNING if brain.poses == 0 or brain.drops.total else logging.INFO
        log.log(
            level,
            "robot %d: %d commands, %d twists, %d stops, %d poses, dropped %s",
            brain.id, brain.commands, brain.twists, brain.stops, brain.poses, brain.drops.summary(),
        )  # fmt: skip


def unheard_robots(brains: list[RobotBrain], options: Ros2Options) -> list[str]:
    """A line for each robot of ``brains`` that has sent no pose at all: the topic and
    type the bridge listens on, the likely mistake (a TurtleBot publishes Odometry on
    /odom, not PoseStamped on /robot<id>/pose)."""
    return [
        f"robot {brain.id}: no pose on {robot_topic(options.pose_topic, brain.id)} "
        f"({options.pose_type}) in ROS 2 domain {options.domain_id} in {SILENT_AFTER:g} s: does "
        "the robot publish there, with that type, in that domain (--pose-topic, --pose-type, "
        "--domain-id: the robots' ROS_DOMAIN_ID)?"
        for brain in brains
        if brain.poses == 0 and not brain.drops.total
    ]


def _hold_token(
    session: zenoh.Session,
    swarm: str,
    brain: RobotBrain,
    now: float,
    alive: dict[int, zenoh.LivelinessToken],
) -> None:
    """The robot's covswarm liveliness token exists exactly while its pose is fresh."""
    visible = brain.visible(now)
    if visible and brain.id not in alive:
        alive[brain.id] = session.liveliness().declare_token(
            protocol.alive_key(swarm, "robot", brain.id)
        )
        log.info("robot %d visible", brain.id)
    elif not visible and brain.id in alive:
        alive.pop(brain.id).undeclare()
        log.warning(
            "robot %d: no valid pose for %.1f s, token withdrawn", brain.id, brain.pose_timeout
        )


class StatePublisher:
    """``--publish-state``: S(t), the poses and e_a of the swarm, as ROS 2 topics."""

    def __init__(
        self, session: zenoh.Session, node: Ros2Node, swarm: str, options: Ros2Options
    ) -> None:
        base = check_topic(options.state_namespace)
        self.frame = options.frame
        self.view = MissionView()
        ring = zenoh.handlers.RingChannel
        self.inputs = [
            (session.declare_subscriber(protocol.domain_key(swarm), ring(4)), self.view.on_domain),
            (session.declare_subscriber(protocol.status_key(swarm), ring(4)), self.view.on_status),
        ]
        self.poses_in = session.declare_subscriber(protocol.all_poses_selector(swarm), ring(1024))
        self.domain = node.publisher(f"{base}/domain", cdr.POLYGON_STAMPED)
        self.poses = node.publisher(f"{base}/poses", cdr.POSE_ARRAY)
        self.error = node.publisher(f"{base}/error", cdr.FLOAT64)
        self._next = 0.0

    def tick(self, now: float, wall: float) -> None:
        for subscriber, handle in self.inputs:
            while (sample := subscriber.try_recv()) is not None:
                handle(sample.payload.to_bytes())
        while (sample := self.poses_in.try_recv()) is not None:
            self.view.on_pose(sample.payload.to_bytes(), now)
        if now < self._next:
            return
        self._next = now + 1.0 / STATE_RATE
        if (vertices := self.view.polygon()) is not None:
            self.domain.put(cdr.encode_polygon_stamped(vertices, wall, self.frame))
        self.poses.put(cdr.encode_pose_array(self.view.poses(now), wall, self.frame))
        if (error := self.view.error()) is not None:
            self.error.put(cdr.encode_float64(error))


def _type_option(kind: dict[str, str], name: str, default: str, help_text: str):
    return click.option(
        name, type=click.Choice(sorted(kind)), default=default, show_default=True, help=help_text
    )


@click.group("bridge")
def bridge_group() -> None:
    """Bridges that let other robot stacks take simulated robots' places."""


@bridge_group.command("ros2")
@click.option("--ids", required=True, help="Robot ids this bridge drives, e.g. 0-9.")
@connect_option("Zenoh router, e.g. tcp/127.0.0.1:7447.")
@click.option("--swarm", required=True, help="Swarm (run) name, as given to covswarm run.")
@click.option("--domain-id", type=int, default=0, show_default=True, help="ROS_DOMAIN_ID.")
@click.option(
    "--cmd-topic",
    default="/robot{id}/cmd_vel",
    show_default=True,
    help="Each robot's command topic ({id}: its id).",
)
@_type_option(cdr.COMMAND_TYPES, "--cmd-type", "Twist", "Message type of the command topic.")
@click.option(
    "--pose-topic",
    default="/robot{id}/pose",
    show_default=True,
    help="Each robot's pose topic ({id}: its id).",
)
@_type_option(cdr.POSE_TYPES, "--pose-type", "PoseStamped", "Message type of the pose topic.")
@float_option(
    "--axle",
    low=0.0,
    low_open=True,
    default=KHEPERA_IV.wheel_separation,
    help="Wheel separation (m) that turns the agents' rim speeds into v and omega.",
)
@click.option("--frame", default="map", show_default=True, help="frame_id of --publish-state.")
@click.option("--publish-state", is_flag=True, help="Publish S(t), poses and e_a to ROS 2.")
@click.option(
    "--state-namespace",
    default="/covswarm",
    show_default=True,
    help="Namespace of the --publish-state topics.",
)
@click.option(
    "--node-name",
    default="covswarm_bridge",
    show_default=True,
    help="The ROS 2 node name the bridge announces.",
)
@float_option(
    "--rate",
    low=1.0,
    high=MAX_RATE,
    default=50.0,
    help="Loop rate (Hz): commands and poses are forwarded at the next tick.",
)
@float_option(
    "--cmd-timeout",
    low=0.01,
    default=0.5,
    help="No command for this long (s): the robot gets a zero Twist.",
)
@float_option(
    "--pose-max-age",
    low=0.01,
    default=0.5,
    help="Drop poses stamped longer ago than this (s), beyond --max-clock-skew: the "
    "limit is their sum (the tracker's clock may run that far behind the bridge's).",
)
@float_option(
    "--pose-timeout",
    low=0.01,
    default=1.0,
    help="Withdraw a robot's liveliness token after this long (s) without a pose.",
)
@click.option("--pose-stamp", type=click.Choice(STAMP_SOURCES), default="message",
              show_default=True,
              help="Stamp poses with the message's stamp, or with the time of receipt "
              "(for pose sources whose clock is not this machine's).")  # fmt: skip
@MAX_CLOCK_SKEW_OPTION
@SECURE_OPTION
@click.option("--verbose", is_flag=True, help="Log at INFO level.")
def ros2_command(
    ids: str,
    connect: tuple[str, ...],
    swarm: str,
    domain_id: int,
    cmd_topic: str,
    cmd_type: str,
    pose_topic: str,
    pose_type: str,
    axle: float,
    frame: str,
    publish_state: bool,
    state_namespace: str,
    node_name: str,
    rate: float,
    cmd_timeout: float,
    pose_max_age: float,
    pose_timeout: float,
    pose_stamp: str,
    max_clock_skew: float = MAX_CLOCK_SKEW,
    secure: Path | None = None,
    verbose: bool = False,
) -> None:
    """Drive ROS 2 robots (rmw_zenoh) as covswarm robots: cmd_vel out, poses in."""
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING)
    ctx = click.get_current_context()
    refuse_unused(ctx, ("frame", "state_namespace"), publish_state, "--publish-state")
    try:
        cdr.typestore()
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from None
    try:
        protocol.check_swarm(swarm)
        robot_ids = protocol.keys.parse_ids(ids)
        options = Ros2Options(
            domain_id=check_domain_id(domain_id),
            cmd_topic=cmd_topic,
            cmd_type=cdr.COMMAND_TYPES[cmd_type],
            pose_topic=pose_topic,
            pose_type=cdr.POSE_TYPES[pose_type],
            node_name=node_name,
            frame=frame,
            publish_state=publish_state,
            state_namespace=state_namespace,
        )
        for option, template in (("--cmd-topic", cmd_topic), ("--pose-topic", pose_topic)):
            try:  # every name is built now, so a bad template fails here
                for rid in robot_ids:
                    robot_topic(template, rid)
            except ValueError as exc:
                raise click.BadParameter(str(exc), param_hint=option) from None
        node_token_key(domain_id, "0", 0, node_name)
        try:
            check_topic(state_namespace)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--state-namespace") from None
        brains = [
            RobotBrain(
                rid,
                options.pose_type,
                axle=axle,
                cmd_timeout=cmd_timeout,
                pose_max_age=pose_max_age,
                pose_timeout=pose_timeout,
                max_clock_skew=max_clock_skew,
                stamp_source=pose_stamp,
            )
            for rid in robot_ids
        ]
        config = session_config(list(connect), None, "client", secure=secure, role="bridge")
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    with watch_expiry(secure, "bridge"):  # its certificate's end stops it
        run_bridge(brains, swarm, config, options, rate)
