"""Records of a run: run.mcap read back with the mcap reader, trajectories.csv, the live
Foxglove server (a real WebSocket client speaking foxglove.sdk.v1) and ``covswarm replay``.

The simulator's record is checked against an independent in-process ``simulate()`` of the
same options; the distributed run's record is in test_records_e2e.py.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap.records import Schema

from covswarm.deploy.simulate import sim_command, simulate
from covswarm.mission.scenario_files import load_scenario
from covswarm.records.recorder import (
    CELL_PERIOD,
    METADATA_NAME,
    RunRecorder,
    sim_stride,
)
from covswarm.records.replay import decoder_factories, frame_times, replay_command
from covswarm.records.trajectories import read_trajectories

AGENTS, DURATION, SEED = 4, 2.0, 3
SCENE_TOPICS = {"/robots", "/domain", "/cells", "/arena"}


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "passage"
    result = CliRunner().invoke(
        sim_command,
        ["--scenario", "passage", "--agents", str(AGENTS), "--duration", str(DURATION),
         "--seed", str(SEED), "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out


def read_mcap(path: Path) -> tuple[dict, dict, dict]:
    """(summary, {topic: [(log_time ns, decoded)]}, metadata) of a run.mcap."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=decoder_factories())
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        messages: dict[str, list] = {}
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return summary, messages, metadata


def test_sim_writes_run_mcap_with_foxglove_schemas(sim_dir: Path) -> None:
    summary, messages, metadata = read_mcap(sim_dir / "run.mcap")
    schemas = {
        channel.topic: (summary.schemas[channel.schema_id].name, channel.message_encoding)
        for channel in summary.channels.values()
    }
    assert {t: schemas[t] for t in SCENE_TOPICS} == {
        t: ("foxglove.SceneUpdate", "protobuf") for t in SCENE_TOPICS
    }
    assert schemas["/error"] == ("covswarm.ErrorSample", "json")

    # Counts: duration x rate (+ the sample at t = 0), team size entities per pose message.
    dt = load_scenario("passage").dt
    stride = sim_stride(dt)
    rate = 1.0 / (stride * dt)
    expected = round(DURATION * rate) + 1
    counts = {
        summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
    }
    assert counts["/robots"] == counts["/domain"] == counts["/error"] == expected
    assert DURATION / CELL_PERIOD <= counts["/cells"] <= DURATION / CELL_PERIOD + 1
    assert all(len(update.entities) == AGENTS for _, update in messages["/robots"])
    assert all(len(update.entities) == AGENTS for _, update in messages["/cells"])
    assert [update.entities[0].id for _, update in messages["/domain"]] == ["S"] * expected

    # Log times are mission times, in order, on every channel and across the file.
    robot_times = np.array([ns for ns, _ in messages["/robots"]]) / 1e9
    np.testing.assert_allclose(robot_times, np.arange(expected) * stride * dt, atol=1e-9)
    in_file = [ns for topic in messages for ns, _ in messages[topic]]
    with (sim_dir / "run.mcap").open("rb") as stream:
        in_file = [
            m.log_time for _, _, m in make_reader(stream).iter_messages(log_time_order=False)
        ]
    assert in_file == sorted(in_file) and in_file[0] == 0

    run = metadata[METADATA_NAME]
    assert run["scenario"] == "passage" and run["source"] == "sim"
    assert json.loads(run["agents"]) == AGENTS and json.loads(run["seed"]) == SEED
    assert json.loads(run["kappa"]) == load_scenario("passage").kappa
    assert "law" in run and json.loads(run["versions"])["foxglove-sdk"].startswith("0.")
    assert json.loads(run["obstacle_polygons"]) == [
        o.vertices.tolist() for o in load_scenario("passage").world.obstacles
    ]

    # The recorded poses are the simulator's: an independent in-process run of the options.
    reference = simulate(load_scenario("passage"), agents=AGENTS, duration=DURATION, seed=SEED)
    for k, (_, update) in enumerate(messages["/robots"]):
        step = k * stride
        for entity in update.entities:
            i = int(entity.id)
            pose = entity.arrows[0].pose
            assert pose.position.x == pytest.approx(reference.trajectories[step, i, 0], abs=1e-9)
            assert pose.position.y == pytest.approx(reference.trajectories[step, i, 1], abs=1e-9)
            yaw = 2 * math.atan2(pose.orientation.z, pose.orientation.w)
            wrapped = math.remainder(yaw - reference.headings[step, i], 2 * math.pi)
            assert abs(wrapped) < 1e-6
    error = [sample["e_a"] for _, sample in messages["/error"]]
    np.testing.assert_allclose(error, reference.error[::stride], rtol=1e-12)


def test_sim_trajectories_csv_has_every_robot_at_the_pose_rate(sim_dir: Path) -> None:
    rows = read_trajectories(sim_dir / "trajectories.csv")
    dt = load_scenario("passage").dt
    step = sim_stride(dt) * dt
    times = np.unique(rows[:, 0])
    np.testing.assert_allclose(np.diff(times), step, atol=1e-4)
    assert times[0] == 0 and times[-1] == pytest.approx(DURATION, abs=1e-4)
    for ident in range(AGENTS):
        mine = rows[rows[:, 1] == ident]
        np.testing.assert_array_equal(mine[:, 0], times)  # one row per robot per time
    reference = simulate(load_scenario("passage"), agents=AGENTS, duration=DURATION, seed=SEED)
    last = rows[rows[:, 0] == times[-1]]
    np.testing.assert_allclose(last[:, 2:4], reference.trajectories[-1], atol=1e-5)


def test_replay_gif_has_one_frame_per_step_of_mission_time(sim_dir: Path) -> None:
    from PIL import Image

    out = sim_dir / "replay.gif"
    fps, speed = 5.0, 1.0
    result = CliRunner().invoke(
        replay_command,
        [str(sim_dir), "--out", str(out), "--fps", str(fps), "--speed", str(speed), "--dpi", "40"],
    )
    assert result.exit_code == 0, result.output
    expected = len(frame_times(DURATION, fps, speed))
    assert expected == round(DURATION * fps / speed) + 1
    with Image.open(out) as gif:
        assert gif.n_frames == expected
        assert gif.info["duration"] == pytest.approx(1000 / fps, abs=1)


def test_replay_mp4_without_ffmpeg_says_so(sim_dir: Path, monkeypatch) -> None:
    from matplotlib import animation

    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    result = CliRunner().invoke(replay_command, [str(sim_dir), "--out", str(sim_dir / "r.mp4")])
    assert result.exit_code != 0
    assert "ffmpeg" in result.output and "gif" in result.output.lower()
    assert not (sim_dir / "r.mp4").exists()


def test_replay_refuses_a_folder_without_a_record(tmp_path: Path) -> None:
    result = CliRunner().invoke(replay_command, [str(tmp_path)])
    assert result.exit_code != 0 and "run.mcap" in result.output
    (tmp_path / "run.mcap").write_bytes(b"not an mcap")
    result = CliRunner().invoke(replay_command, [str(tmp_path)])
    assert result.exit_code != 0 and "cannot read" in result.output


@pytest.mark.parametrize(
    ("option", "value"), [("--fps", "nan"), ("--speed", "nan"), ("--speed", "inf")]
)
def test_replay_refuses_a_rate_that_is_not_a_finite_number(
    tmp_path: Path, option: str, value: str
) -> None:
    """Refused before the record is read: click's FloatRange alone let "nan" through (it
    fails every comparison with a bound) and "inf" past a missing upper bound."""
    result = CliRunner().invoke(replay_command, [str(tmp_path), option, value])
    assert result.exit_code == 2 and "is not a finite number" in result.output, result.output


def test_steering_events_keep_their_time_and_the_file_stays_ordered(tmp_path: Path) -> None:
    with RunRecorder(tmp_path, run_metadata={"scenario": "unit"}) as recorder:
        recorder.poses(1.0, [0], np.array([[0.0, 0.0, 0.0]]))
        recorder.steering(0.5, {"accepted": True, "reason": "ok"})  # arrived a tick late
        recorder.error(1.5, float("nan"), 1)
    _, messages, _ = read_mcap(tmp_path / "run.mcap")
    ((log_time, event),) = messages["/steering"]
    assert log_time == 1_000_000_000 and event == {"t": 0.5, "accepted": True, "reason": "ok"}
    assert messages["/error"][0][1] == {"e_a": None, "robots": 1}  # NaN is not JSON


def test_agent_states_are_recorded_as_sent_and_read_back_decoded(tmp_path: Path) -> None:
    """/agents/states holds each payload's bytes (msgpack, schema covswarm.AgentState) at
    its log time; read_agent_states decodes them with covswarm.protocol and counts the
    malformed; a robot's state at a time is the newest logged by then."""
    from covswarm.protocol import AgentState
    from covswarm.records.replay import read_agent_states

    relay = ((3, 1.2, 2.0, 0.0, 0.1), (7, 0.8, 2.1, -0.05, 0.0))
    states = [
        AgentState(55, 1.0, 2.0, 1.7e9, (3, 7), vx=0.1, vy=-0.1, relay=relay),
        AgentState(3, 1.2, 2.0, 1.7e9 + 0.01, (55,), stats={"rate_hz": 9.9, "rx_total": 12}),
        AgentState(55, 1.01, 1.99, 1.7e9 + 0.1, (3,)),
    ]
    sent = [state.encode() for state in states]
    with RunRecorder(tmp_path, run_metadata={}) as recorder:
        recorder.agent_states(3.0, sent[:2])
        recorder.agent_states(2.0, [])  # nothing to record: no message
        recorder.agent_states(3.25, [sent[2], b"\x81\xa1v\x01"])  # a map with no fields
    assert recorder.counts["states"] == 4
    with (tmp_path / "run.mcap").open("rb") as stream:
        reader = make_reader(stream)
        raw = [
            (schema.name, channel.message_encoding, message.log_time, message.data)
            for schema, channel, message in reader.iter_messages(topics=["/agents/states"])
        ]
    assert raw == [
        ("covswarm.AgentState", "msgpack", t, data)
        for t, data in zip(
            [3 * 10**9] * 2 + [3_250_000_000] * 2, [*sent, b"\x81\xa1v\x01"], strict=True
        )
    ]
    record = read_agent_states(tmp_path / "run.mcap")
    assert record.t == [3.0, 3.0, 3.25] and record.states == states and record.rejected == 1
    assert record.at(55, 2.9) is None
    assert record.at(55, 3.2) == (3.0, states[0])
    assert [entry[0] for entry in record.at(55, 3.2)[1].relay] == [3, 7]  # whom it relayed
    assert record.at(55, 10.0) == (3.25, states[2])
    assert [state for _, state in record.of(3)] == [states[1]]


def test_live_server_sends_robot_poses_over_foxglove_sdk_v1() -> None:
    """A WebSocket client speaking foxglove.sdk.v1 subscribes to /robots and decodes a pose."""
    import websockets
    from mcap_protobuf.decoder import DecoderFactory

    poses = np.array([[1.25, -0.5, 0.75], [0.0, 2.0, -2.0]])
    recorder = RunRecorder(None, run_metadata={"scenario": "unit"}, live_port=0)
    stop = threading.Event()

    def feed() -> None:
        k = 0
        while not stop.is_set():
            recorder.poses(0.05 * k, [3, 8], poses)
            k += 1
            time.sleep(0.05)

    async def first_pose() -> tuple[dict, bytes]:
        url = f"ws://127.0.0.1:{recorder.live_port}"
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"
            channel = None
            while channel is None:
                message = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if message["op"] == "advertise":
                    channel = next(
                        (c for c in message["channels"] if c["topic"] == "/robots"), None
                    )
            subscribe = {
                "op": "subscribe",
                "subscriptions": [{"id": 42, "channelId": channel["id"]}],
            }
            await ws.send(json.dumps(subscribe))
            while not isinstance(data := await asyncio.wait_for(ws.recv(), 10), bytes):
                pass
            return channel, data

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        channel, data = asyncio.run(first_pose())
    finally:
        stop.set()
        feeder.join()
        recorder.close()
    assert channel["schemaName"] == "foxglove.SceneUpdate" and channel["encoding"] == "protobuf"
    opcode, subscription, log_time = struct.unpack_from("<BIQ", data)
    assert (opcode, subscription) == (1, 42) and log_time % 50_000_000 == 0
    schema = Schema(
        id=1,
        name=channel["schemaName"],
        encoding="protobuf",
        data=base64.b64decode(channel["schema"]),
    )
    update = DecoderFactory().decoder_for("protobuf", schema)(data[13:])
    assert [e.id for e in update.entities] == ["3", "8"]
    for entity, (x, y, theta) in zip(update.entities, poses, strict=True):
        pose = entity.arrows[0].pose
        assert (pose.position.x, pose.position.y) == pytest.approx((x, y))
        assert 2 * math.atan2(pose.orientation.z, pose.orientation.w) == pytest.approx(theta)


def test_shipped_layouts_are_the_generated_ones_and_name_recorded_channels() -> None:
    from covswarm.coordinator.monitor import HEADLINE_STATS
    from covswarm.records import recorder
    from covswarm.records.layout import SCENE_TOPICS as LAYOUT_TOPICS
    from covswarm.records.layout import STATS_PATHS, layout_files

    docs = Path(__file__).resolve().parent.parent / "docs"
    for name, text in layout_files().items():
        assert (docs / name).read_text(encoding="utf-8") == text, f"regenerate docs/{name}"
    scene_topics = {recorder.ROBOTS_TOPIC, recorder.DOMAIN_TOPIC, recorder.CELLS_TOPIC}
    assert scene_topics | {recorder.ARENA_TOPIC} == set(LAYOUT_TOPICS)
    lichtblick = json.loads(layout_files()["lichtblick-layout.json"])
    plotted = [
        p["value"] for key, c in lichtblick["configById"].items() if key.startswith("Plot")
        for p in c["paths"]
    ]  # fmt: skip
    assert plotted == ["/error.e_a", *STATS_PATHS]
    for path in STATS_PATHS:
        topic, _, stat = path.partition(".mean.")
        assert topic == recorder.AGENT_STATS_TOPIC and stat in HEADLINE_STATS


def test_live_view_on_a_taken_port_is_a_clear_error(tmp_path: Path) -> None:
    import socket

    from covswarm.records.live import port_is_free
    from covswarm.records.recorder import LiveViewError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert not port_is_free(port)
        with pytest.raises(LiveViewError, match=f"127.0.0.1:{port}"):
            RunRecorder(tmp_path, run_metadata={}, live_port=port)
    assert port_is_free(port) and port_is_free(0)
    assert not (tmp_path / "run.mcap").exists()  # nothing half-written


def test_timed_layers_place_every_observed_pose_once_at_its_measured_time() -> None:
    from covswarm.records.observations import timed_layers

    wall, t, t_prev = 1000.0, 5.0, 4.95

    def seen(ident: int, seq: int, age: float) -> list[float]:
        return [ident, seq, wall - age, float(ident), float(seq), 0.1 * seq]

    observations = np.array([
        seen(7, 11, 0.01),  # robot 7's second pose of the tick, listed first
        seen(2, 4, 0.03),
        seen(7, 10, 0.04),
        seen(9, 1, 0.5),  # measured before the previous record: clipped to t_prev
        seen(3, 8, -0.2),  # stamped in the future (another host's clock): clipped to t
        seen(4, 5, 0.02),  # not newer than what was recorded for robot 4: stale
        seen(2, 4, 0.03),  # the same pose delivered twice: stale
    ])  # fmt: skip
    layers, stale = timed_layers(observations, t, t_prev, wall, {4: 4.99})
    assert stale == 2
    assert [layer.ids for layer in layers] == [[2, 3, 7, 9], [7]]
    np.testing.assert_allclose(layers[0].times, [4.97, 5.0, 4.96, 4.95])
    np.testing.assert_allclose(layers[1].times, [4.99])
    np.testing.assert_allclose(layers[0].poses[2], [7.0, 10.0, 1.0])  # seq 10 before 11
    np.testing.assert_allclose(layers[1].poses[0], [7.0, 11.0, 1.1])
    assert timed_layers(np.empty((0, 6)), t, t_prev, wall, {}) == ([], 0)


def test_timed_layers_agree_with_a_plain_loop_on_random_ticks() -> None:
    """The vectorised layers against the rule written as a loop, on random arrivals."""
    from covswarm.records.observations import timed_layers

    rng = np.random.default_rng(4)
    for _ in range(50):
        m = int(rng.integers(1, 40))
        rows = np.column_stack([
            rng.integers(0, 6, m), rng.permutation(m), 1000 - rng.uniform(-0.05, 0.2, m),
            rng.normal(size=(m, 3)),
        ])  # fmt: skip
        last = {int(i): float(rng.uniform(4.9, 5.0)) for i in rng.integers(0, 6, 3)}
        layers, stale = timed_layers(rows, 5.0, 4.9, 1000.0, last)
        expected: dict[int, list[tuple[float, int]]] = {}
        dropped = 0
        for ident in sorted(set(rows[:, 0].astype(int))):
            latest = last.get(ident, -np.inf)
            mine = rows[rows[:, 0] == ident]
            for row in mine[np.argsort(mine[:, 1])]:
                when = min(max(5.0 - (1000.0 - row[2]), 4.9), 5.0)
                if when <= latest:
                    dropped += 1
                    continue
                expected.setdefault(ident, []).append((when, int(row[1])))
                latest = when
        got: dict[int, list[tuple[float, int]]] = {}
        for layer in layers:
            assert layer.ids == sorted(set(layer.ids))  # no robot twice in a layer
            for ident, when, pose in zip(layer.ids, layer.times, layer.poses, strict=True):
                seq = int(rows[(rows[:, 0] == ident) & (rows[:, 3] == pose[0]), 1][0])
                got.setdefault(ident, []).append((float(when), seq))
        assert stale == dropped and got == expected


def test_replay_merges_a_ticks_messages_and_lets_silent_robots_go(tmp_path: Path) -> None:
    from covswarm.records.replay import read_recording

    with RunRecorder(tmp_path, run_metadata={"scenario": "unit"}) as recorder:
        recorder.poses(1.0, [0, 1], np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.5]]))
        recorder.poses(1.0, [1], np.array([[1.5, 1.0, 0.5]]))  # robot 1's second pose
        recorder.poses(3.0, [0], np.array([[0.2, 0.0, 0.0]]))  # robot 1 silent for 2 s
    record = read_recording(tmp_path / "run.mcap")
    assert record.pose_t == [1.0, 3.0]
    assert record.poses[0] == {0: (0.0, 0.0, 0.0), 1: (1.5, 1.0, pytest.approx(0.5))}
    assert record.poses[1] == {0: (0.2, 0.0, 0.0)}


def test_a_resumed_coordinator_records_beside_the_first_part(tmp_path: Path) -> None:
    from covswarm.records.recorder import record_names

    with RunRecorder(tmp_path, run_metadata={}) as first:
        first.poses(0.0, [0], np.zeros((1, 3)))
    for k in (1, 2):
        with RunRecorder(tmp_path, run_metadata={}, continued=True) as part:
            part.poses(1.0 * k, [0], np.ones((1, 3)))
        assert part.mcap_path == tmp_path / f"run-{k}.mcap"
        assert (tmp_path / f"trajectories-{k}.csv").is_file()
    assert record_names(tmp_path, False) == ("run.mcap", "trajectories.csv")
    assert len(read_trajectories(tmp_path / "trajectories.csv")) == 1  # not overwritten


def test_run_refuses_a_live_view_it_cannot_serve(tmp_path: Path) -> None:
    import socket

    from covswarm.deploy.launcher import run_command
    from covswarm.deploy.plan import RunConfig, coordinator_config
    from covswarm.mission.scenario_files import load_scenario
    from covswarm.runtime.options import config_argv

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = CliRunner().invoke(
            run_command, ["--foxglove", str(port), "--out", str(tmp_path / "run")]
        )
    assert result.exit_code == 2 and "already in use" in result.output
    result = CliRunner().invoke(run_command, ["--foxglove", "--no-coordinator", "--swarm", "s"])
    assert result.exit_code == 2 and "coordinator serves the live view" in result.output

    def recording_args(seed: int, foxglove: int | None, record: bool, states: bool) -> list[str]:
        run = RunConfig(
            seed=seed, foxglove=foxglove, record=record, record_states=states, swarm="s",
            out=Path("o"),
        )  # fmt: skip
        argv = config_argv(coordinator_config(run, load_scenario("passage"), "e"))
        return [a for k, a in enumerate(argv) if a in RECORDING or argv[k - 1] in RECORDING]

    RECORDING = {"--seed", "--foxglove", "--record", "--no-record"}
    RECORDING |= {"--record-states", "--no-record-states"}
    assert recording_args(3, None, True, True) == ["--record", "--record-states", "--seed", "3"]
    assert recording_args(3, 0, False, False) == [
        "--no-record", "--no-record-states", "--foxglove", "0", "--seed", "3",
    ]  # fmt: skip


def test_a_port_in_time_wait_is_free_and_a_listening_one_is_not() -> None:
    """The live view's port check after a viewed run: the server closed its viewer's
    connection first, so that connection sits in TIME-WAIT on the port for up to a minute.
    A second ``--foxglove`` run must start at once (the servers bind with SO_REUSEADDR)."""
    import socket

    from covswarm.records.live import port_is_free

    with socket.socket() as listener:
        # as the servers bind (tokio under foxglove-sdk, asyncio under the console); Linux
        # lets a bind reuse a TIME-WAIT port only if both sides set the option
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        assert not port_is_free(port)  # a listener: in use
        client = socket.create_connection(("127.0.0.1", port))
        server_side, _ = listener.accept()
        server_side.close()  # the server closes first: its end goes to TIME-WAIT
        assert client.recv(1) == b""  # the client saw the close ...
        client.close()  # ... and answers it, so the server's end completes to TIME-WAIT
    deadline = time.monotonic() + 5
    while not in_time_wait(port) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert in_time_wait(port), "no TIME-WAIT socket: the test did not set up its case"
    assert port_is_free(port)
    with socket.socket() as plain:  # what the check did before: refused for up to a minute
        with pytest.raises(OSError):
            plain.bind(("127.0.0.1", port))
    server = __import__("foxglove").start_server(name="again", host="127.0.0.1", port=port)
    server.stop()  # and the SDK's server binds it too


def in_time_wait(port: int) -> bool:
    """Whether /proc/net/tcp lists a socket on local port ``port`` in TIME-WAIT (state 06)."""
    rows = Path("/proc/net/tcp").read_text().splitlines()[1:]
    return any(row.split()[1].endswith(f":{port:04X}") and row.split()[3] == "06" for row in rows)


def test_clients_offering_only_the_old_subprotocol_are_refused() -> None:
    """foxglove-sdk 0.30 speaks foxglove.sdk.v1 only and has no option to accept the older
    foxglove.websocket.v1 (docs/records.md says which viewers connect): a client offering
    only the old name gets HTTP 400, one offering both gets the new one. If a later SDK
    accepts the old name, this fails and the docs should say so."""
    import websockets

    recorder = RunRecorder(None, run_metadata={"scenario": "unit"}, live_port=0)
    url = f"ws://127.0.0.1:{recorder.live_port}"

    async def handshake(offered: list[str]) -> str:
        try:
            async with websockets.connect(url, subprotocols=offered) as ws:
                return str(ws.subprotocol)
        except websockets.InvalidStatus as exc:
            return f"HTTP {exc.response.status_code}"

    try:
        assert asyncio.run(handshake(["foxglove.websocket.v1"])) == "HTTP 400"
        both = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
        assert asyncio.run(handshake(both)) == "foxglove.sdk.v1"
    finally:
        recorder.close()


def test_the_stats_schema_declares_every_stat_an_agent_reports() -> None:
    """/agents/stats declares its fields, so a viewer's plot path /agents/stats.mean.rate_hz
    has a type: every stat of AgentBrain.stats() (but the per-reason drop counters, which
    additionalProperties types), for the team mean and for each agent."""
    from covswarm.agent.brain import AgentBrain
    from covswarm.records import recorder as rec
    from covswarm.records.layout import STATS_PATHS

    schema = json.loads(rec.json_schema(rec.AGENT_STATS_SCHEMA, rec._STATS_SCHEMA).data)
    mean = schema["properties"]["mean"]
    each = schema["properties"]["agents"]["items"]
    reported = {k for k in AgentBrain(0).stats() if not k.startswith("drop_")}
    assert reported == set(mean["properties"]), reported ^ set(mean["properties"])
    assert set(each["properties"]) == reported | {"id"}
    for fields in (mean["properties"], each["properties"]):
        assert all(field["type"] in ("number", "integer") for field in fields.values())
    for obj in (mean, each):
        assert obj["additionalProperties"]["type"] == "number"  # drop_<reason>
    for path in STATS_PATHS:  # the layouts' plot paths resolve to a declared number
        topic, field, stat = path.split(".")
        assert topic == rec.AGENT_STATS_TOPIC and field == "mean"
        assert mean["properties"][stat]["type"] == "number"


KILLED_WRITER = """
import os, sys
import numpy as np
from covswarm.records import recorder
recorder.MCAP_CHUNK_SIZE = 4096  # several chunks: the writer dies with some written
r = recorder.RunRecorder(sys.argv[1], run_metadata={"scenario": "unit"})
from covswarm.protocol import AgentState
for k in range(200):
    r.poses(0.05 * k, [0, 1], np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]) + 0.001 * k)
    r.agent_states(0.05 * k, [AgentState(1, 1.0, 0.0, 1.7e9 + k, (0,)).encode()])
os._exit(0)  # as SIGKILL: no summary, no footer
"""


def test_a_resumed_runs_parts_replay_in_order_the_killed_one_read_to_its_end(
    tmp_path: Path,
) -> None:
    # A coordinator killed mid-run leaves run.mcap without its footer; the one resumed with
    # --resume writes run-1.mcap beside it (records.md). Replay reads both, in order.
    import subprocess
    import sys

    from covswarm.records.replay import read_agent_states, read_recording, recording_parts

    subprocess.run([sys.executable, "-c", KILLED_WRITER, str(tmp_path)], check=True, timeout=60)
    with pytest.raises(Exception):  # noqa: B017 -- what any MCAP reader says of it
        read_mcap(tmp_path / "run.mcap")
    with RunRecorder(tmp_path, run_metadata={"scenario": "unit"}, continued=True) as recorder:
        for k in range(40):
            recorder.poses(12.0 + 0.05 * k, [0, 1], np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    parts = recording_parts(tmp_path)
    assert [p.name for p in parts] == ["run.mcap", "run-1.mcap"]
    record = read_recording(parts)
    assert record.truncated == ["run.mcap"]
    first = [t for t in record.pose_t if t < 12.0]
    assert len(first) >= 150 and first[0] == 0.0  # all but what the killed writer had buffered
    assert record.pose_t[-1] == pytest.approx(12.0 + 0.05 * 39)
    assert record.pose_t == sorted(record.pose_t)
    result = CliRunner().invoke(
        replay_command,
        [str(tmp_path), "--out", str(tmp_path / "r.gif"), "--fps", "2", "--dpi", "30"],
    )
    assert result.exit_code == 0, result.output
    assert "run.mcap ends early" in result.output
    # The agents' states of the killed part, read to its end as well, in order.
    states = read_agent_states(tmp_path / "run.mcap")
    assert states.truncated and states.rejected == 0 and len(states.t) >= 150
    assert [s.stamp - 1.7e9 for s in states.states] == pytest.approx(range(len(states.t)))


def test_what_is_not_an_mcap_file_is_refused_as_such(tmp_path: Path) -> None:
    from covswarm.records.replay import read_agent_states, read_recording

    (tmp_path / "run.mcap").write_bytes(bytes(range(256)) * 20)
    for read in (read_agent_states, read_recording):
        with pytest.raises(ValueError, match="run.mcap: not an MCAP file"):
            read(tmp_path / "run.mcap")
    result = CliRunner().invoke(replay_command, [str(tmp_path)])
    assert result.exit_code == 1 and "not an MCAP file" in result.output
