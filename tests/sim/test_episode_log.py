"""Episode logs: exact round trip, reproducible bytes, atomic files, Foxglove-readable layout and
the minimal replay format."""

from __future__ import annotations

import json
import math
import os
import stat
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from d2a_core.errors import UsageError
from d2a_core.sim.episode_log import (
    CarPose,
    EpisodeRecorder,
    StaticScene,
    read_episode,
    read_replay,
)

STEPS = 200
DT = 0.05
EGO_RADIUS, OPP_RADIUS = 50.0, 47.0
EGO_RATE, OPP_RATE = 0.31, 0.29  # rad/s around the circle
METADATA = {"track": "circle", "seed": 7, "intent": "pass", "gains": {"k": 0.25, "n": [1, 2]}}


def _ring(radius: float, points: int = 65) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * math.pi, points)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(points)])


SCENE = StaticScene(
    track_name="circle",
    left_edge=_ring(54.0),
    right_edge=_ring(44.0),
    barriers=[(_ring(56.0), 1.2), (_ring(42.0), 1.2)],
    finish_line=np.array([[44.0, 0.0, 0.0], [54.0, 0.0, 0.0]]),
    centreline=_ring(49.0),
)


def _step(k: int) -> tuple[float, dict[str, CarPose], dict[str, dict]]:
    """Two cars driving counter-clockwise on concentric circles (tangent heading)."""
    t = k * DT
    a_ego, a_opp = EGO_RATE * t, OPP_RATE * t + 0.2
    cars = {
        "ego": CarPose(EGO_RADIUS * math.cos(a_ego), EGO_RADIUS * math.sin(a_ego), 0.6,
                       a_ego + math.pi / 2),
        "opp": CarPose(OPP_RADIUS * math.cos(a_opp), OPP_RADIUS * math.sin(a_opp), 0.6,
                       a_opp + math.pi / 2, colour=(0.0, 1.0, 0.0, 1.0)),
    }
    human = [math.sin(0.1 * k), 0.5 + 0.001 * k]
    state = {
        "ego": {
            "s": EGO_RADIUS * a_ego,
            "e": 0.1 * math.sin(0.05 * k),
            "speed": EGO_RADIUS * EGO_RATE,
            "yaw_rate": EGO_RATE,
            "action": {"human": human, "assistant": [0.01 * k, -0.2], "applied": human},
            "reward": {"pass": 1.0 / (k + 1), "progress": 0.3 * k},
            "intent": None if k < 20 else ("pass" if k < 120 else "follow"),
            "off_track": k % 50 == 0,
            "lap": k // 100,
        },
        "opp": {"s": OPP_RADIUS * a_opp, "e": 0.0, "speed": OPP_RADIUS * OPP_RATE},
    }
    return t, cars, state


def _record(path: Path, steps: int = STEPS, metadata: dict = METADATA) -> Path:
    with EpisodeRecorder(path, SCENE, metadata, dt=DT) as recorder:
        for k in range(steps):
            recorder.log_step(*_step(k))
    return path


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _record(tmp_path_factory.mktemp("episode") / "episode.mcap")


def test_round_trip_is_exact(log_path: Path) -> None:
    episode = read_episode(log_path)
    steps = [_step(k) for k in range(STEPS)]
    np.testing.assert_array_equal(episode.times, [t for t, _, _ in steps])
    assert episode.agents == ["ego", "opp"]
    for car in ("ego", "opp"):
        expected = np.array([[c[car].x, c[car].y, c[car].z, c[car].yaw] for _, c, _ in steps])
        assert episode.poses[car].dtype == np.float64
        np.testing.assert_array_equal(episode.poses[car], expected)  # bit-exact float64
    ego = episode.state["ego"]
    for field in ("s", "e", "speed", "yaw_rate"):
        np.testing.assert_array_equal(ego[field], [s["ego"][field] for _, _, s in steps])
    assert ego["action.human"].shape == (STEPS, 2)
    assistant = [s["ego"]["action"]["assistant"] for _, _, s in steps]
    np.testing.assert_array_equal(ego["action.assistant"], assistant)
    np.testing.assert_array_equal(ego["reward.pass"], [1.0 / (k + 1) for k in range(STEPS)])
    assert ego["off_track"].dtype == bool and ego["off_track"].sum() == 4
    assert ego["lap"].dtype == np.int64 and ego["lap"][-1] == 1
    assert list(ego["intent"][[0, 19, 20, 119, 120]]) == [None, None, "pass", "pass", "follow"]
    # the opponent's speed agrees with its path: arc length per step / dt
    step_length = np.linalg.norm(np.diff(episode.poses["opp"][:, :2], axis=0), axis=1)
    np.testing.assert_allclose(step_length / DT, episode.state["opp"]["speed"][1:], rtol=1e-3)


def test_metadata_round_trip(log_path: Path) -> None:
    episode = read_episode(log_path)
    assert episode.metadata == METADATA
    assert episode.dt == DT and episode.track_name == "circle"


def test_identical_episodes_give_identical_bytes(tmp_path: Path) -> None:
    first = _record(tmp_path / "a.mcap", steps=60)
    second = _record(tmp_path / "b.mcap", steps=60)
    assert first.read_bytes() == second.read_bytes()
    other_seed = _record(tmp_path / "c.mcap", steps=60, metadata={**METADATA, "seed": 8})
    assert other_seed.read_bytes() != first.read_bytes()


def test_exception_inside_recorder_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "failed.mcap"
    with pytest.raises(RuntimeError, match="simulator diverged"):
        with EpisodeRecorder(path, SCENE, METADATA, dt=DT) as recorder:
            for k in range(10):
                recorder.log_step(*_step(k))
            raise RuntimeError("simulator diverged")
    assert list(tmp_path.iterdir()) == []  # neither the log nor its temporary file


def test_failed_rerecording_keeps_the_previous_file(tmp_path: Path) -> None:
    path = _record(tmp_path / "episode.mcap", steps=5)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="first step"):
        with EpisodeRecorder(path, SCENE, METADATA, dt=DT) as recorder:
            t, cars, state = _step(0)
            recorder.log_step(t, cars, state)
            t, cars, state = _step(1)
            del state["ego"]["intent"]  # layout must not change mid-episode
            recorder.log_step(t, cars, state)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["episode.mcap"]


def test_file_is_valid_mcap_with_foxglove_schemas(log_path: Path) -> None:
    with log_path.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        kinds = {
            topic: (c.message_encoding, summary.schemas[c.schema_id].name,
                    summary.schemas[c.schema_id].encoding)
            for topic, c in channels.items()
        }
        assert summary.statistics is not None
        counts = {summary.channels[channel_id].topic: count
                  for channel_id, count in summary.statistics.channel_message_counts.items()}
    assert kinds["/scene/track"] == ("protobuf", "foxglove.SceneUpdate", "protobuf")
    assert kinds["/scene/cars"] == ("protobuf", "foxglove.SceneUpdate", "protobuf")
    assert kinds["/tf"] == ("protobuf", "foxglove.FrameTransforms", "protobuf")
    assert kinds["/state/ego"][0] == "json" and kinds["/state/ego"][2] == "jsonschema"
    assert kinds["/state/opp"][0] == "json" and kinds["/state/opp"][2] == "jsonschema"
    assert counts == {"/scene/track": 1, "/scene/cars": STEPS, "/tf": STEPS,
                      "/state/ego": STEPS, "/state/opp": STEPS}
    schema = json.loads(summary.schemas[channels["/state/ego"].schema_id].data)
    properties = schema["properties"]
    assert properties["speed"] == {"type": "number"}
    assert properties["reward"]["properties"]["pass"] == {"type": "number"}
    assert properties["action"]["properties"]["human"] == {"type": "array", "items": {"type": "number"}}
    assert properties["off_track"] == {"type": "boolean"}


# -- protobuf: enough of the wire format to check where Foxglove would draw things ------------

def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, i


def _fields(data: bytes) -> dict[int, list]:
    """Protobuf fields by number: varints as int, 64-bit as float, length-delimited as bytes."""
    fields: dict[int, list] = {}
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 1:
            value, i = struct.unpack("<d", data[i:i + 8])[0], i + 8
        elif wire == 2:
            size, i = _varint(data, i)
            value, i = data[i:i + size], i + size
        elif wire == 5:
            value, i = struct.unpack("<f", data[i:i + 4])[0], i + 4
        else:
            raise AssertionError(f"unexpected wire type {wire}")
        fields.setdefault(number, []).append(value)
    return fields


def _xyz(message: bytes, names: str = "xyz") -> list[float]:
    fields = _fields(message)  # proto3 leaves zero values out
    return [fields.get(i + 1, [0.0])[0] for i in range(len(names))]


def test_car_cubes_are_drawn_at_the_car_poses(log_path: Path) -> None:
    with log_path.open("rb") as stream:
        messages = [m for _, _, m in make_reader(stream).iter_messages(topics=["/scene/cars"])]
    assert len(messages) == STEPS
    for k in (0, 77, STEPS - 1):
        t, cars, _ = _step(k)
        assert messages[k].log_time == round(t * 1e9)
        entities = [_fields(e) for e in _fields(messages[k].data)[2]]  # SceneUpdate.entities
        by_id = {e[3][0].decode(): e for e in entities}  # SceneEntity.id
        assert set(by_id) == {"car/ego", "car/opp"}
        for name, pose in cars.items():
            entity = by_id[f"car/{name}"]
            assert entity[2][0] == b"world"  # frame_id
            cube = _fields(entity[8][0])  # SceneEntity.cubes
            cube_pose = _fields(cube[1][0])
            assert _xyz(cube_pose[1][0]) == pytest.approx([pose.x, pose.y, pose.z], abs=1e-12)
            qx, qy, qz, qw = _xyz(cube_pose[2][0], "xyzw")
            assert (qx, qy) == (0.0, 0.0)
            drawn_yaw = 2.0 * math.atan2(qz, qw)
            assert math.remainder(drawn_yaw - pose.yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
            assert _xyz(cube[2][0]) == pytest.approx([4.5, 1.9, 1.2])  # default car size


def test_static_scene_has_road_barriers_and_finish(log_path: Path) -> None:
    with log_path.open("rb") as stream:
        (message,) = [m for _, _, m in make_reader(stream).iter_messages(topics=["/scene/track"])]
    assert message.log_time == 0
    entities = [_fields(e) for e in _fields(message.data)[2]]
    by_id = {e[3][0].decode(): e for e in entities}
    assert set(by_id) == {"track/road", "track/centreline", "track/finish", "track/barriers"}
    road = by_id["track/road"]
    assert len(road[11]) == 2  # SceneEntity.lines: the two edges
    triangles = _fields(road[12][0])  # SceneEntity.triangles: the road surface
    indices = struct.unpack(f"<{len(triangles[5][0]) // 4}I", triangles[5][0])  # packed fixed32
    assert len(indices) == 3 * 2 * 64  # 64 quads between 65-point edges, two triangles each
    assert max(indices) == 2 * 65 - 1
    assert len(by_id["track/barriers"][12]) == 2  # one wall per barrier
    finish_line = _fields(by_id["track/finish"][11][0])
    assert [_xyz(p)[:2] for p in finish_line[5]] == [[44.0, 0.0], [54.0, 0.0]]  # LinePrimitive.points


# -- replays and errors ---------------------------------------------------------------------

def _write_plain_mcap(path: Path, topic: str, messages: list[dict], schema: bool) -> None:
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="hand-written test replay")
        schema_id = writer.register_schema(
            name="Lap", encoding="jsonschema", data=json.dumps({"type": "object"}).encode()
        ) if schema else 0
        channel_id = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
        for index, message in enumerate(messages):
            time_ns = 5_000_000_000 + 100_000_000 * index  # log times need not start at 0
            writer.add_message(channel_id, log_time=time_ns, data=json.dumps(message).encode(),
                               publish_time=time_ns)
        writer.finish()


def _lap(steps: int = 40) -> list[dict]:
    return [
        {"t": 0.1 * k, "x": 30.0 * math.cos(0.02 * k), "y": 30.0 * math.sin(0.02 * k),
         "yaw": 0.02 * k + math.pi / 2, "speed": 6.0, "s": 0.6 * k, "e": -0.25}
        for k in range(steps)
    ]


@pytest.mark.parametrize("schema", [True, False])
def test_hand_written_minimal_replay_is_read(tmp_path: Path, schema: bool) -> None:
    path = tmp_path / "lap.mcap"
    lap = _lap()
    _write_plain_mcap(path, "/state/rival", lap, schema)
    episode = read_replay(path)
    assert episode.agents == ["rival"] and episode.metadata == {} and episode.dt is None
    np.testing.assert_array_equal(episode.times, [m["t"] for m in lap])
    expected = np.array([[m["x"], m["y"], 0.0, m["yaw"]] for m in lap])  # z defaults to 0
    np.testing.assert_array_equal(episode.poses["rival"], expected)
    np.testing.assert_array_equal(episode.state["rival"]["s"], [m["s"] for m in lap])


def test_recorded_episode_is_a_valid_replay(log_path: Path) -> None:
    episode = read_replay(log_path, "ego")
    assert len(episode) == STEPS
    with pytest.raises(UsageError, match="several agents"):
        read_replay(log_path)
    with pytest.raises(UsageError, match="no channel /state/ghost"):
        read_replay(log_path, "ghost")


def test_replay_missing_fields_is_a_usage_error(tmp_path: Path) -> None:
    path = tmp_path / "lap.mcap"
    _write_plain_mcap(path, "/state/rival", [{k: v for k, v in m.items() if k != "speed"}
                                             for m in _lap()], schema=False)
    with pytest.raises(UsageError, match=r"lap\.mcap.*speed"):
        read_replay(path)


def test_missing_corrupt_and_channelless_files_are_usage_errors(tmp_path: Path, log_path: Path) -> None:
    with pytest.raises(UsageError, match=r"nowhere\.mcap does not exist"):
        read_episode(tmp_path / "nowhere.mcap")
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(log_path.read_bytes()[: log_path.stat().st_size // 2])
    with pytest.raises(UsageError, match=r"truncated\.mcap is not a readable MCAP file"):
        read_episode(truncated)
    flipped = bytearray(log_path.read_bytes())
    flipped[len(flipped) // 3] ^= 0xFF  # inside a compressed chunk: CRC or decompression fails
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(flipped))
    with pytest.raises(UsageError, match=r"damaged\.mcap"):
        read_episode(damaged)
    other = tmp_path / "other.mcap"
    _write_plain_mcap(other, "/imu", _lap(3), schema=False)
    with pytest.raises(UsageError, match=r"other\.mcap has no /state/<agent>"):
        read_episode(other)
    no_time = tmp_path / "no_time.mcap"
    _write_plain_mcap(no_time, "/state/rival", [{**m, "t": None} for m in _lap(3)], schema=False)
    with pytest.raises(UsageError, match=r"no_time\.mcap: channel /state/rival lacks a numeric 't'"):
        read_episode(no_time)


def test_non_finite_values_read_back_as_nan(tmp_path: Path) -> None:
    path = tmp_path / "nan.mcap"
    with EpisodeRecorder(path, SCENE, {}, dt=DT) as recorder:
        for k in range(3):
            speed = [1.0, math.nan, math.inf][k]
            recorder.log_step(k * DT, {"ego": CarPose(k, 0.0, 0.0, 0.0)},
                              {"ego": {"speed": speed, "action": [speed, 0.5]}})
    episode = read_episode(path)
    speed = episode.state["ego"]["speed"]
    assert speed[0] == 1.0 and np.isnan(speed[1]) and np.isnan(speed[2])
    assert np.isnan(episode.state["ego"]["action"][1, 0]) and episode.state["ego"]["action"][1, 1] == 0.5
    np.testing.assert_array_equal(episode.poses["ego"][:, 0], [0.0, 1.0, 2.0])


def test_unwritable_path_is_a_usage_error(tmp_path: Path) -> None:
    blocker = tmp_path / "not_a_directory"
    blocker.write_text("")
    with pytest.raises(UsageError, match=r"cannot write episode log .*not_a_directory"):
        with EpisodeRecorder(blocker / "episode.mcap", SCENE, {}, dt=DT):
            pass
    assert [p.name for p in tmp_path.iterdir()] == ["not_a_directory"]


def test_log_gets_default_file_permissions(log_path: Path) -> None:
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(log_path.stat().st_mode) == 0o666 & ~umask


def test_step_times_must_increase(tmp_path: Path) -> None:
    path = tmp_path / "time.mcap"
    with pytest.raises(ValueError, match="after the previous step"):
        with EpisodeRecorder(path, SCENE, {}, dt=DT) as recorder:
            recorder.log_step(*_step(3))
            recorder.log_step(*_step(2))
    assert not path.exists()


def test_scene_and_state_inputs_are_checked(tmp_path: Path) -> None:
    flat = StaticScene("flat", [[0, 0], [1, 0]], [[0, 1], [1, 1]], [], [[0, 0], [0, 1]])
    assert flat.left_edge.shape == (2, 3) and np.all(flat.left_edge[:, 2] == 0.0)
    with pytest.raises(ValueError, match="left_edge contains non-finite"):
        StaticScene("bad", [[0, 0, math.nan]], [[0, 1, 0]], [], [[0, 0], [0, 1]])
    with pytest.raises(ValueError, match=r"barriers\[0\] height must be positive"):
        StaticScene("bad", [[0, 0]], [[0, 1]], [([[0, 0], [1, 0]], 0.0)], [[0, 0], [0, 1]])
    path = tmp_path / "clash.mcap"
    with pytest.raises(ValueError, match=r"state of 'ego' has fields \['x'\]"):
        with EpisodeRecorder(path, flat, {}, dt=DT) as recorder:
            recorder.log_step(0.0, {"ego": CarPose(0.0, 0.0, 0.0, 0.0)}, {"ego": {"x": 1.0}})
    assert not path.exists()
