"""`d2a make-track` end to end through the CLI: artifacts, replays that finish, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.sim.replay import OpponentReplay
from d2a_core.tracks import Track, load_track

OVAL_CSV = Path(__file__).parent / "tracks" / "fixtures" / "oval_chicane.csv"


def _check_replays_stay_on_track(store: Store, result: dict, track: Track, car_width: float = 1.9) -> None:
    for opp in result["opponents"]:
        replay = OpponentReplay.from_log(store.path(opp["id"], "replay.mcap"), "opponent", dt=0.1)
        w_left, w_right = track.width_at(replay.s)
        assert np.all(replay.e + car_width / 2 <= w_left) and np.all(replay.e - car_width / 2 >= -w_right)
        assert replay.s[-1] >= track.finish_s
        assert replay.t[-1] >= opp["finish_time_s"] > 0


def test_make_track_straightaway_smoke(cli, store_dir):
    res = cli("make-track", "straightaway", "--preset", "smoke", "--json", store=store_dir)
    assert res.code == 0, res.stderr
    out = res.json
    assert out["name"] == "straightaway" and out["length_m"] == 370.0 and out["elevation_range_m"] == 0.0
    assert len(out["opponents"]) == 2  # the smoke preset's count
    store = Store(store_dir)
    assert store.resolve("track/straightaway") == out["id"]
    track = load_track(store.path(out["id"], "track.npz"))
    assert track.finish_s == 370.0 and track.barriers and track.barriers[0].side == "right"
    _check_replays_stay_on_track(store, out, track)
    paces = [o["pace"] for o in out["opponents"]]
    assert paces == sorted(paces) and paces[0] == 0.6 and paces[-1] == 0.8
    times = [o["finish_time_s"] for o in out["opponents"]]
    assert times[0] > times[-1]  # the slower pace finishes later
    replay = store.get(out["opponents"][0]["id"])
    assert replay.inputs == [out["id"]] and replay.kind == "replay"
    assert store.resolve("track/straightaway/opponents/1") == out["opponents"][1]["id"]
    # the same command again gives the same artifacts
    again = cli("make-track", "straightaway", "--preset", "smoke", "--json", store=store_dir).json
    assert again["id"] == out["id"] and [o["id"] for o in again["opponents"]] == [o["id"] for o in out["opponents"]]
    # another seed drives other lines: new replays, same track
    other = cli("make-track", "straightaway", "--preset", "smoke", "--seed", "5", "--json", store=store_dir).json
    assert other["id"] == out["id"] and other["opponents"][0]["id"] != out["opponents"][0]["id"]


def test_make_track_hairpin_has_hills_and_opponents_finish(cli, store_dir):
    res = cli("make-track", "hairpin", "--preset", "smoke", "--set", "opponents.count=3", "--json", store=store_dir)
    assert res.code == 0, res.stderr
    out = res.json
    assert out["length_m"] == 960.0 and out["elevation_range_m"] >= 10.0
    store = Store(store_dir)
    _check_replays_stay_on_track(store, out, load_track(store.path(out["id"], "track.npz")))


def test_make_track_from_csv_section(cli, store_dir):
    res = cli("make-track", str(OVAL_CSV), "--start", "100", "--length", "500", "--name", "oval-cut",
              "--preset", "smoke", "--json", store=store_dir)
    assert res.code == 0, res.stderr
    out = res.json
    assert out["name"] == "oval-cut"
    store = Store(store_dir)
    track = load_track(store.path("track/oval-cut", "track.npz"))
    assert abs(track.length - 500.0) < 1.0
    assert "source.csv" in store.get("track/oval-cut").files


def test_make_track_errors(cli, store_dir, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nwidth: {left: 6, right: 6}\nsegments:\n  - straight: {length: -5}\nfinish_s: 10\n")
    res = cli("make-track", str(bad), "--preset", "smoke", "--json", store=store_dir)
    assert res.code == 2 and "bad.yaml" in res.json["error"]["message"]
    res = cli("make-track", "hairpn", "--preset", "smoke", "--json", store=store_dir)
    assert res.code == 2 and "hairpin" in res.json["error"]["message"]
    csv = tmp_path / "broken.csv"
    csv.write_text("# x_m, y_m, w_tr_right_m, w_tr_left_m\n0,0,5,5\n1,0,5\n")
    res = cli("make-track", str(csv), "--preset", "smoke", "--json", store=store_dir)
    assert res.code == 2 and "broken.csv" in res.json["error"]["message"] and ":3" in res.json["error"]["message"]


def test_a_flat_out_driver_can_pass_every_default_straightaway_replay(cli, store_dir):
    """The pass intent must be achievable: from its grid slot behind the opponent, an ego at full
    throttle reaches the finish well before even the fastest default replay does."""
    from d2a_core.sim.race_env import EnvConfig
    from d2a_core.sim.vehicle import Vehicle

    out = cli("make-track", "straightaway", "--preset", "smoke", "--json", store=store_dir).json
    store = Store(store_dir)
    track = load_track(store.path(out["id"], "track.npz"))
    grid, env = track.start_grid, EnvConfig()
    assert grid.opponent.s > grid.ego.s  # the ego starts behind
    x, y, _ = track.from_frenet(grid.ego.s, grid.ego.e)
    vehicle = Vehicle()
    vehicle.reset(float(x), float(y), float(track.heading_at(grid.ego.s)), env.start_speed_m_s)
    t = 0.0
    while grid.ego.s + (vehicle.state.x - float(x)) < track.finish_s:  # the straightaway runs along +x
        vehicle.step(0.0, 1.0, dt=env.dt)
        t += env.dt
    fastest = max(out["opponents"], key=lambda o: o["pace"])
    replay = OpponentReplay.from_log(store.path(fastest["id"], "replay.mcap"), "opponent", dt=env.dt)
    opponent_s = float(np.interp(t, replay.t, replay.s))
    assert track.finish_s - opponent_s >= 10.0, f"pace {fastest['pace']}: opponent at {opponent_s:.1f} m"
