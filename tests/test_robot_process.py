"""Pure logic of the simulated robot process (no Zenoh)."""

from __future__ import annotations

import math
import subprocess
import sys

import msgpack
import numpy as np
import pytest

from covswarm import protocol
from covswarm.protocol.messages import MAX_ANGLE, MAX_COORD, MAX_SEQ, MAX_STAMP
from covswarm.sim_robot.process import (
    REST_POSE_RATE,
    PosePayloads,
    PoseSchedule,
    RobotSim,
    step_robots,
    step_with_commands,
)
from covswarm.tvd.drive import DiffDrive, integrate_one
from covswarm.world.model import World

STAMP = 1.7e9


def command(left: float, right: float, robot_id: int = 1, stamp: float = STAMP) -> bytes:
    return protocol.WheelCommand(
        id=robot_id, left=left, right=right, stamp=stamp, seq=1, pose_stamp=STAMP
    ).encode()


def raw_command(**overrides: object) -> bytes:
    d = {"v": 1, "id": 1, "left": 0.1, "right": 0.1, "stamp": STAMP, "seq": 1, "pose_stamp": 0.0}
    return msgpack.packb({**d, **overrides})


def test_drives_straight_from_last_command() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), cmd_timeout=0.5)
    assert sim.on_command(command(0.2, 0.2), now=0.0, now_wall=STAMP)
    for k in range(1, 11):
        sim.step(k * 0.02)
    assert sim.pose == pytest.approx([0.04, 0.0, 0.0], abs=1e-12)


def test_command_timeout_stops_the_wheels() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), cmd_timeout=0.5)
    sim.on_command(command(0.2, 0.2), now=0.0, now_wall=STAMP)
    t = 0.0
    while t < 2.0:
        t += 0.02
        sim.step(t)
    # moved for 0.5 s only, then stopped
    assert sim.pose[0] == pytest.approx(0.1, abs=0.2 * 0.02 + 1e-9)
    assert not sim.wheels.any()
    assert sim.counters.timeouts == 1
    x = sim.pose[0]
    sim.step(t + 1.0)
    assert sim.pose[0] == x


def test_no_command_no_motion() -> None:
    sim = RobotSim(1, (1.0, 2.0, 0.5))
    for k in range(10):
        sim.step(0.1 * k)
    assert sim.pose == pytest.approx([1.0, 2.0, 0.5])


@pytest.mark.parametrize(
    "payload",
    [
        raw_command(left=math.nan),
        raw_command(right=math.inf),
        raw_command(left=100.0),
        raw_command(left="fast"),
        raw_command(extra=1),
        b"\x93garbage",
        b"",
    ],
)
def test_bad_commands_are_dropped_and_never_integrated(payload: bytes) -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0))
    sim.on_command(command(0.1, 0.1), now=0.0, now_wall=STAMP)
    assert not sim.on_command(payload, now=0.01, now_wall=STAMP)
    assert sim.drops.total == 1
    assert sim.wheels == pytest.approx([0.1, 0.1])  # the last valid command holds
    sim.step(0.02)
    assert np.all(np.isfinite(sim.pose))


def test_command_for_another_robot_is_ignored() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0))
    assert not sim.on_command(command(0.3, 0.3, robot_id=2), now=0.0, now_wall=STAMP)
    assert sim.drops.counts["wrong_id"] == 1
    assert not sim.wheels.any()


def test_wheels_clamped_to_robot_limit() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), robot=DiffDrive(max_wheel_speed=0.5))
    sim.on_command(command(2.0, 2.0), now=0.0, now_wall=STAMP)
    sim.step(0.1)
    assert sim.pose[0] == pytest.approx(0.05)


def test_stall_does_not_teleport() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), cmd_timeout=0.5)
    sim.on_command(command(0.2, 0.2), now=0.0, now_wall=STAMP)
    sim.step(0.0)
    sim.on_command(
        command(0.2, 0.2), now=10.0, now_wall=STAMP
    )  # a command arrives after a 10 s freeze
    sim.step(10.0)
    assert sim.pose[0] <= 0.2 * 0.5 + 1e-12


def test_turning_in_place_wraps_heading() -> None:
    sim = RobotSim(1, (0.0, 0.0, 3.0))
    sim.on_command(command(-0.1, 0.1), now=0.0, now_wall=STAMP)
    sim.step(0.2)
    message = sim.pose_message(STAMP, 0)
    assert -math.pi <= message.theta < math.pi
    assert (message.x, message.y) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert protocol.Pose.decode(message.encode()) == message


def test_bad_construction_rejected() -> None:
    with pytest.raises(ValueError):
        RobotSim(1, (math.nan, 0.0, 0.0))
    with pytest.raises(ValueError):
        RobotSim(1, (0.0, 0.0, 0.0), cmd_timeout=0.0)
    with pytest.raises(ValueError):
        RobotSim(-1, (0.0, 0.0, 0.0))


def test_robot_process_does_not_import_scipy() -> None:
    code = (
        "import sys, covswarm.sim_robot.process; "
        "bad = [m for m in ('scipy', 'matplotlib') if m in sys.modules]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_drops_per_reason_are_one_line_at_exit() -> None:
    import json

    from covswarm.sim_robot.process import drops_line, gather_drops

    quiet, noisy = RobotSim(1, (0.0, 0.0, 0.0)), RobotSim(3, (0.0, 0.0, 0.0))
    assert drops_line([quiet, noisy]) is None
    for _ in range(500):  # a flood of garbage and of commands for robot 1 on robot 3's key
        assert not noisy.on_command(b"\xc1", 0.0, STAMP)
        assert not noisy.on_command(command(0.1, 0.1, robot_id=1), 0.0, STAMP)
    assert not noisy.on_command(command(0.1, 0.1, robot_id=3), 0.0, STAMP + 10.0)  # old
    line = drops_line([quiet, noisy])
    assert line is not None and line.startswith("robot drops ")
    counts = json.loads(line.removeprefix("robot drops "))
    assert counts == {"3": {"undecodable": 500, "wrong_id": 500, "stamp_old": 1}}
    # What the launcher gathers into summary.json from a robot process's log, other lines
    # and a torn last line left out; two processes' lines add up per robot.
    log = f'INFO starting\nWARNING {line}\nWARNING {line}\nrobot drops {{"3": {{"und\n'
    assert gather_drops(log) == {"3": {"undecodable": 1000, "wrong_id": 1000, "stamp_old": 2}}
    assert gather_drops("nothing dropped\n") == {}


def _fleet(n: int, seed: int, world=None) -> list[RobotSim]:
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    return [RobotSim(i, tuple(p), cmd_timeout=0.5, world=world) for i, p in enumerate(poses)]


def _drive_history(sims: list[RobotSim], step, seed: int) -> list[np.ndarray]:
    """Commands at random times (some robots never commanded, some time out, some get a
    command on the tick they are stepped), steps every 0.05 s by ``step(sims, now)``; the
    (n, 3) poses after each step."""
    rng = np.random.default_rng([seed, 1])
    out = []
    for k in range(1, 30):
        now = 0.05 * k
        for sim in sims:
            if sim.id % 4 != 0 and now < 0.9 and rng.random() < 0.4:
                left, right = rng.uniform(-1.2, 1.2, 2)  # some beyond the rim limit
                assert sim.on_command(command(left, right, robot_id=sim.id), now, STAMP)
        out.append(step(sims, now))
    return out


def test_a_batch_steps_every_robot_as_its_own_step_does() -> None:
    """step_robots (one numpy batch) equals each robot stepped alone, to 1e-12, over a
    history with clamped wheels, command timeouts and commands arriving on a tick."""
    batch = _drive_history(_fleet(40, 3), step_robots, 3)
    alone = _drive_history(
        _fleet(40, 3), lambda sims, now: np.array([sim.step(now) for sim in sims]), 3
    )
    for got, want in zip(batch, alone, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert not np.allclose(batch[0], batch[-1])  # the robots did move


def test_a_batch_equals_the_scalar_arc_per_robot() -> None:
    """Independent reference: tvd.drive.integrate_one, one robot at a time in floats."""
    sims = _fleet(25, 5)
    rng = np.random.default_rng(9)
    wheels = rng.uniform(-1.0, 1.0, (25, 2))
    wheels[:3] = [[0.2, 0.2], [-0.1, 0.1], [0.0, 0.0]]  # straight, in place, still
    for sim, (left, right) in zip(sims, wheels, strict=True):
        sim.on_command(command(left, right, robot_id=sim.id), 0.0, STAMP)
    want = [tuple(sim.pose.tolist()) for sim in sims]
    before = 0.0
    for now in (0.05, 0.1, 0.13, 0.2):
        got = step_robots(sims, now)
        arcs = zip(want, wheels.tolist(), strict=True)
        want = [integrate_one(*p, *w, now - before) for p, w in arcs]
        np.testing.assert_allclose(got, np.array(want), rtol=0, atol=1e-12)
        before = now


def test_a_batch_stops_at_walls_as_one_robot_does() -> None:
    world = World((-1.0, 1.0, -1.0, 1.0))
    walled = _fleet(12, 7, world)
    batch = _drive_history(walled, step_robots, 7)
    assert sum(sim.counters.contact_stops for sim in walled) > 0
    alone = _drive_history(
        _fleet(12, 7, world), lambda sims, now: np.array([sim.step(now) for sim in sims]), 7
    )
    for got, want in zip(batch, alone, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def _tick_history(sims: list[RobotSim], tick, seed: int) -> list[np.ndarray]:
    """Ticks every 0.05 s, the wall clock at STAMP + the monotonic one; on each, some robots
    receive one or two commands (none after 0.9 s, so they time out), sent at random times
    since the last tick (some exactly at it or at the tick), handed to ``tick(sims,
    received, now)`` in the order sent as (robot, payload, sent); the (n, 3) poses after
    each tick."""
    rng = np.random.default_rng([seed, 2])
    out = []
    for k in range(1, 30):
        now = 0.05 * k
        received = []
        for sim in sims:
            for _ in range(rng.choice(3, p=[0.5, 0.3, 0.2]) if now < 0.9 else 0):
                sent = rng.choice([now - 0.05, now, now - rng.uniform(0.0, 0.05)])
                wheels = rng.uniform(-1.2, 1.2, 2)
                received.append((sim, command(*wheels, robot_id=sim.id, stamp=STAMP + sent), sent))
        received.sort(key=lambda item: item[2])
        out.append(tick(sims, received, now))
    return out


def _command_then_step(sims: list[RobotSim], received: list, now: float) -> np.ndarray:
    """The reference: each command drives its robot alone up to its arrival (when sent,
    read off the wall clock as the robot does: at 1.7e9 s its resolution is 2e-7 s) and
    changes its wheels there, then the batch steps the rest."""
    for sim, payload, sent in received:
        arrival = min(max(now - ((STAMP + now) - (STAMP + sent)), sim._last_step), now)
        assert sim.on_command(payload, arrival, STAMP + sent)
    return step_robots(sims, now)


@pytest.mark.parametrize("world", [None, World((-1.0, 1.0, -1.0, 1.0))])
def test_a_tick_applies_each_command_from_its_stamp(world: World | None) -> None:
    """step_with_commands (rounds of commands, each round's robots driven to their
    commands' stamps as one batch, then the whole batch to the tick) drives every robot as
    applying each command alone when it was sent and then stepping does: poses to 1e-12,
    and the same commands, timeouts and wall stops counted."""
    ticked, reference = _fleet(30, 4, world), _fleet(30, 4, world)

    def tick(sims: list[RobotSim], received: list, now: float) -> np.ndarray:
        pairs = [(sim, payload) for sim, payload, _ in received]
        return step_with_commands(sims, pairs, now, STAMP + now)

    got = _tick_history(ticked, tick, 4)
    want = _tick_history(reference, _command_then_step, 4)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert not np.allclose(got[0], got[-1])  # the robots did move
    assert [s.counters for s in ticked] == [s.counters for s in reference]
    assert sum(s.counters.timeouts for s in ticked) > 0
    if world is not None:
        assert sum(s.counters.contact_stops for s in ticked) > 0


def test_robots_not_driven_yet_publish_at_the_rest_rate() -> None:
    """Over 2 s of 16 Hz ticks (binary-exact times): driven robots' poses at 16 Hz, resting
    ones' at REST_POSE_RATE, always on a tick where the driven ones publish too."""
    schedule = PoseSchedule(16.0, start=0.0)
    due = [schedule.due(k / 16) for k in range(32)]
    assert sum(full for full, _ in due) == 32
    assert sum(rest for _, rest in due) == round(2.0 * REST_POSE_RATE)
    assert all(full for full, rest in due if rest)
    slow = PoseSchedule(2.0, start=0.0)  # a pose rate under the rest rate: every pose
    assert all(full == rest for full, rest in (slow.due(0.05 * k) for k in range(40)))


def test_a_robot_counts_as_driven_from_its_first_moving_command() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0))
    assert sim.on_command(command(0.0, 0.0), now=0.0, now_wall=STAMP)
    assert sim.on_command(command(-0.0, 0.0), now=0.05, now_wall=STAMP)
    assert not sim.counters.driven  # zero wheels: the pose cannot change
    assert sim.on_command(command(0.0, 0.1), now=0.1, now_wall=STAMP)
    assert sim.counters.driven
    sim.on_command(command(0.0, 0.0), now=0.2, now_wall=STAMP)
    assert sim.counters.driven  # stays: a stopped robot moving again must not wait


class _OneRobot:
    """The reference for the command timeout and the elapsed time: one robot in plain
    floats as RobotSim stepped it alone before step_robots took both as a batch (open
    floor, tvd.drive.integrate_one)."""

    def __init__(self, pose: tuple[float, float, float], cmd_timeout: float) -> None:
        self.pose, self.wheels, self.cmd_timeout = pose, (0.0, 0.0), cmd_timeout
        self.last_command: float | None = None
        self.last_step, self.timeouts = 0.0, 0

    def command(self, left: float, right: float, now: float) -> None:
        if now != self.last_step:
            self.step(now)
        self.wheels, self.last_command = (left, right), now

    def step(self, now: float) -> None:
        commanded = self.last_command is not None and now - self.last_command <= self.cmd_timeout
        if not commanded and self.wheels != (0.0, 0.0):
            self.timeouts += 1
            self.wheels = (0.0, 0.0)
        dt = min(max(now - self.last_step, 0.0), self.cmd_timeout)
        self.last_step = now
        if dt > 0.0 and self.wheels != (0.0, 0.0):
            self.pose = integrate_one(*self.pose, *self.wheels, dt)


def test_ticks_time_out_and_cap_the_elapsed_time_as_one_robot_alone_did() -> None:
    """Ticks with commands (step_with_commands) against :class:`_OneRobot` per robot: each
    robot its own cmd_timeout, some never commanded, some commanded then silent, a tick
    repeated, a clock step back and a stall longer than any timeout; poses to 1e-12, the
    wheels and the timeouts counted."""
    rng = np.random.default_rng(11)
    n = 24
    starts = [(*rng.uniform(-1, 1, 2), rng.uniform(-math.pi, math.pi)) for _ in range(n)]
    timeouts = rng.uniform(0.15, 0.6, n)
    sims = [
        RobotSim(i, p, cmd_timeout=t, now=0.0)
        for i, (p, t) in enumerate(zip(starts, timeouts, strict=True))
    ]
    refs = [_OneRobot(p, t) for p, t in zip(starts, timeouts, strict=True)]
    times = (
        [0.05 * k for k in range(1, 20)]
        + [0.95, 0.94, 2.0]
        + [2.0 + 0.07 * k for k in range(1, 15)]
    )
    for now in times:
        received = []
        for i in range(n):
            if i % 5 != 0 and rng.random() < (0.5 if i % 3 else 0.1):
                left, right = rng.uniform(-1.2, 1.2, 2)
                received.append((sims[i], command(left, right, robot_id=i)))
                refs[i].command(float(left), float(right), now)
        poses = step_with_commands(sims, received, now, STAMP)
        for ref in refs:
            ref.step(now)
        np.testing.assert_allclose(poses, [ref.pose for ref in refs], rtol=0, atol=1e-12)
        assert [tuple(sim.wheels) for sim in sims] == [ref.wheels for ref in refs]
    assert [sim.counters.timeouts for sim in sims] == [ref.timeouts for ref in refs]
    assert sum(ref.timeouts for ref in refs) > n // 2  # the silences did stop wheels


def test_a_command_acts_from_its_stamp_within_the_tick() -> None:
    """A command stamped 30 ms after one tick drives its robot on the old wheels for those
    30 ms and on its own for the 20 ms to the next (exact arcs, integrate_one); one stamped
    before the last tick (a clock behind) acts from that tick, one stamped after this tick
    (a clock ahead) from this tick."""

    def tick(robot: RobotSim, left: float, right: float, sent: float, now: float) -> np.ndarray:
        payload = command(left, right, stamp=STAMP + sent)
        return step_with_commands([robot], [(robot, payload)], now, STAMP + now)[0]

    sim = RobotSim(1, (0.0, 0.0, 0.0), now=0.0)
    tick(sim, 0.1, 0.1, 0.0, 0.0)
    pose = tick(sim, 0.05, 0.15, 0.08, 0.1)
    want = integrate_one(*integrate_one(0.0, 0.0, 0.0, 0.1, 0.1, 0.08), 0.05, 0.15, 0.02)
    # 1e-7 m: the wall clock's resolution at 1.7e9 s (2e-7 s) at 0.15 m/s
    np.testing.assert_allclose(pose, want, rtol=0, atol=1e-7)
    behind, ahead = RobotSim(1, (0.0, 0.0, 0.0), now=0.0), RobotSim(1, (0.0, 0.0, 0.0), now=0.0)
    for robot in (behind, ahead):
        tick(robot, 0.1, 0.1, 0.0, 0.0)
    tick(behind, 0.0, 0.2, -0.01, 0.05)
    tick(ahead, 0.0, 0.2, 0.07, 0.05)
    want_behind = integrate_one(0.0, 0.0, 0.0, 0.0, 0.2, 0.05)
    np.testing.assert_allclose(behind.pose, want_behind, rtol=0, atol=1e-12)
    want_ahead = integrate_one(0.0, 0.0, 0.0, 0.1, 0.1, 0.05)
    np.testing.assert_allclose(ahead.pose, want_ahead, rtol=0, atol=1e-12)
    assert ahead.wheels.tolist() == [0.0, 0.2]  # from the tick on
    assert behind.counters.commands == ahead.counters.commands == 2


def test_pose_payloads_are_the_bytes_pose_encodes() -> None:
    """Row by row Pose(...).encode(), or None where Pose refuses the row (bounds, NaN,
    infinities) or the stamp or sequence number; ids and sequence numbers of every msgpack
    int width."""
    ids = [0, 1, 127, 128, 255, 256, 40000, 65535]
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(-20, 20, (len(ids), 2)), rng.uniform(-7, 7, len(ids))])
    beyond = np.nextafter(MAX_COORD, np.inf)
    edges = [
        (-0.0, 0.0, -0.0), (MAX_COORD, -MAX_COORD, MAX_ANGLE), (0.0, 0.0, -MAX_ANGLE),
        (beyond, 0.0, 0.0), (0.0, -beyond, 0.0), (0.0, 0.0, np.nextafter(MAX_ANGLE, np.inf)),
        (np.nan, 0.0, 0.0), (0.0, np.inf, 0.0), (0.0, 0.0, -np.inf), (1e-300, -5e-324, 1.0),
    ]  # fmt: skip
    ids += list(range(1000, 1000 + len(edges)))
    poses = np.vstack([poses, edges])
    encoder = PosePayloads(ids)
    stamps_seqs = [(STAMP, s) for s in (0, 127, 128, 255, 256, 65536, 2**32, MAX_SEQ)]
    stamps_seqs += [(0.0, 7), (MAX_STAMP, 7), (-1.0, 7), (2 * MAX_STAMP, 7), (STAMP, -1)]
    for stamp, seq in stamps_seqs:
        want = []
        for i, (x, y, theta) in zip(ids, poses.tolist(), strict=True):
            try:
                want.append(
                    protocol.Pose(id=i, x=x, y=y, theta=theta, stamp=stamp, seq=seq).encode()
                )
            except protocol.ProtocolError:
                want.append(None)
        assert encoder.encode(poses, stamp, seq) == want
    assert sum(p is None for p in encoder.encode(poses, STAMP, 1)) == 6
