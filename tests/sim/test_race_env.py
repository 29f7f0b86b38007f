"""`d2a/Race-v0` through the gymnasium API: checker, observation, terminations, rewards, wrappers."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from d2a_core.objectives import RewardConfig
from d2a_core.sim import ENV_ID, make_vector_env
from d2a_core.sim.episode_log import read_episode
from d2a_core.sim.race_env import FAR_AHEAD_M, EnvConfig, RaceEnv, observation_names
from d2a_core.sim.recording import RecordEpisodes
from d2a_core.sim.replay import OpponentReplay
from d2a_core.sim.shared_control import SharedControl, blend
from d2a_core.tracks import build_track


@pytest.fixture(scope="module")
def straight():
    return build_track("straightaway")


@pytest.fixture(scope="module")
def hairpin():
    return build_track("hairpin")


def parked_opponent(track, s: float, e: float, steps: int = 400) -> OpponentReplay:
    """An opponent standing still at (s, e): makes collisions easy to stage."""
    x, y, z = track.from_frenet(s, e)
    yaw = track.heading_at(s)
    n = steps
    return OpponentReplay(t=np.arange(n) * 0.1, x=np.full(n, x), y=np.full(n, y), z=np.full(n, z),
                          yaw=np.full(n, yaw), speed=np.zeros(n), s=np.full(n, s), e=np.full(n, e))


def expected_forfeit(info, window: float = RewardConfig().pass_window_m) -> float:
    """F by hand: minus the gap a car stopped here would still lose inside the pass window."""
    if not (info["collision"] or info["off_track"]):
        return 0.0
    ds, remaining = info["ds"], info["opponent_s_at_limit"] - info["opponent_s"]
    return -max(0.0, min(ds, window) - max(ds - remaining, -window))


def run(env, policy, seed=0, options=None, max_steps=2000):
    obs, info = env.reset(seed=seed, options=options)
    infos, rewards = [info], []
    for _ in range(max_steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        infos.append(info)
        rewards.append(reward)
        if terminated or truncated:
            return infos, rewards, terminated, truncated
    raise AssertionError("episode did not end")


def test_env_checker_passes_through_gym_make(straight):
    env = gym.make(ENV_ID, track=straight, intent="pass", disable_env_checker=True)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    assert env.action_space.shape == (2,)
    env.close()


def test_observation_layout_and_partner_slot(straight):
    env = RaceEnv(straight, intent="pass")
    obs, info = env.reset(seed=0)
    names = observation_names(env.cfg.edge_lookahead_m)
    assert obs.shape == (len(names),) and env.observation_names == names
    assert "intent" not in " ".join(names)
    o = dict(zip(names, obs))
    assert o["partner_steer"] == 0.0 and o["partner_accel"] == 0.0
    assert o["speed"] == pytest.approx(env.cfg.start_speed_m_s, rel=1e-3)
    # the road edges 20 m ahead are ahead of the car, left edge left of it, right edge right of it
    assert o["left_edge_20m_x"] == pytest.approx(20.0, abs=1.0)
    assert o["left_edge_20m_y"] > 0 > o["right_edge_20m_y"]
    assert o["left_edge_20m_y"] - o["right_edge_20m_y"] == pytest.approx(sum(straight.width_at(25.0)), abs=0.2)
    assert o["ds"] == pytest.approx(info["ds"]) and o["ds"] < 0  # the opponent starts ahead
    env.set_partner_action(np.array([0.25, -0.5]))
    obs, *_ = env.step(np.zeros(2))
    o = dict(zip(names, obs))
    assert (o["partner_steer"], o["partner_accel"]) == (0.25, -0.5)


def test_finish_line_terminates_with_finish_reward(straight):
    env = RaceEnv(straight, intent="stay")
    infos, rewards, terminated, truncated = run(env, lambda o: np.array([0.0, 1.0]))
    last = infos[-1]
    assert terminated and not truncated and last["finished"] and not last["collision"]
    assert last["s"] >= straight.finish_s
    assert last["reward_terms"]["finish"] == RewardConfig().finish
    assert last["progress"] == pytest.approx(last["s"] - straight.start_grid.ego.s)


def test_collision_with_opponent_terminates(straight):
    grid = straight.start_grid.ego
    env = RaceEnv(straight, replays=[parked_opponent(straight, grid.s + 30.0, grid.e)], intent="pass")
    infos, rewards, terminated, _ = run(env, lambda o: np.array([0.0, 0.5]))
    last = infos[-1]
    assert terminated and last["collision_car"] and not last["collision_barrier"]
    cfg = RewardConfig()
    assert last["reward_terms"]["collision"] == cfg.collision and last["reward_terms"]["task"] == cfg.collision
    # the opponent stands still: a stopped ego would lose nothing more, so the crash costs r_collision
    assert expected_forfeit(last) == 0.0 and last["reward_terms"]["forfeit_m"] == 0.0
    assert rewards[-1] == pytest.approx(cfg.collision + cfg.c_pass * (last["ds"] - infos[-2]["ds"]))
    assert last["s"] == pytest.approx(grid.s + 30.0 - env.cfg.car_length_m, abs=3.5)


def test_barrier_collision_terminates(straight):
    env = RaceEnv(straight, intent="pass")  # concrete wall on the right
    infos, _, terminated, _ = run(env, lambda o: np.array([-0.3, 0.2]))
    last = infos[-1]
    assert terminated and last["collision_barrier"] and not last["off_track"]
    wall_e = float(np.max(straight.barriers[0].e))  # the wall's road-facing side (negative: right)
    half_diagonal = 0.5 * math.hypot(env.cfg.car_length_m, env.cfg.car_width_m)
    assert wall_e < last["e"] < wall_e + half_diagonal + 0.2  # the body reaches the wall


def test_off_track_terminates(straight):
    env = RaceEnv(straight, intent="pass")  # no barrier on the left
    infos, rewards, terminated, _ = run(env, lambda o: np.array([0.3, 0.2]))
    last = infos[-1]
    assert terminated and last["off_track"] and not last["collision"]
    assert last["e"] > straight.width_at(last["s"])[0] + env.cfg.off_track_margin_m
    cfg = RewardConfig()
    assert last["reward_terms"]["bounds"] == cfg.bounds
    forfeit = expected_forfeit(last)
    assert -2 * cfg.pass_window_m <= forfeit < -100.0  # the opponent drives on: a real forfeit, bounded
    assert rewards[-1] == pytest.approx(cfg.bounds + cfg.c_pass * (last["ds"] - infos[-2]["ds"] + forfeit))


def test_crash_penalty_is_bounded_by_the_window_for_every_intent(straight):
    """Hitting the pit wall early costs r_collision plus the intent's rate on at most 2 W_pass
    metres (the old form charged ~20,000 for every intent on this track)."""
    cfg = RewardConfig()
    for intent, rate in (("pass", cfg.c_pass), ("left", cfg.c_side), ("right", cfg.c_side), ("stay", 0.0)):
        env = RaceEnv(straight, intent=intent)
        infos, rewards, terminated, _ = run(env, lambda o: np.array([-0.3, 0.2]))
        last = infos[-1]
        assert terminated and last["collision_barrier"]
        assert last["reward_terms"]["task"] == cfg.collision
        assert last["reward_terms"]["forfeit_m"] == pytest.approx(expected_forfeit(last))
        assert last["reward_terms"][intent] - last["reward_terms"]["progress"] * (intent == "stay") \
            >= rate * -2 * cfg.pass_window_m - 50.0
        assert rewards[-1] >= cfg.collision + rate * -2 * cfg.pass_window_m - 50.0


def test_a_step_that_finishes_off_the_road_is_off_track_not_finished(straight):
    env = RaceEnv(straight, intent="pass")
    w_left, _ = straight.width_at(straight.finish_s)
    env.reset(seed=0, options={"ego_s": straight.finish_s - 1.0,
                               "ego_e": w_left + env.cfg.off_track_margin_m + 1.0})
    _, reward, terminated, _, info = env.step(np.array([0.0, 0.5]))
    assert terminated and info["s"] >= straight.finish_s
    assert info["off_track"] and not info["finished"]
    assert info["reward_terms"]["finish"] == 0.0 and info["reward_terms"]["bounds"] == RewardConfig().bounds


def test_time_left_is_observed(straight):
    env = RaceEnv(straight, env_config=EnvConfig(time_limit_s=3.0))
    names = env.observation_names
    obs, _ = env.reset(seed=0)
    assert dict(zip(names, obs))["time_left"] == pytest.approx(3.0)
    for k in range(1, 4):
        obs, *_ = env.step(np.zeros(2))
        assert dict(zip(names, obs))["time_left"] == pytest.approx(3.0 - 0.1 * k)


def test_time_limit_truncates(straight):
    env = RaceEnv(straight, env_config=EnvConfig(time_limit_s=2.0))
    infos, _, terminated, truncated = run(env, lambda o: np.array([0.0, 0.0]))
    assert truncated and not terminated and len(infos) - 1 == 20


@pytest.mark.parametrize("intent", ["pass", "stay", "left", "right"])
def test_reward_is_task_plus_intent_term_from_info(straight, intent):
    env = RaceEnv(straight, intent=intent)
    infos, rewards, *_ = run(env, lambda o: np.array([0.05, 0.8]))
    cfg = RewardConfig()
    for prev, info, reward in zip(infos, infos[1:], rewards):
        d_ds = info["ds"] - prev["ds"]
        passing = d_ds if (abs(info["ds"]) <= cfg.pass_window_m or abs(prev["ds"]) <= cfg.pass_window_m) else 0.0
        staying = d_ds if (abs(info["ds"]) <= cfg.stay_window_m or abs(prev["ds"]) <= cfg.stay_window_m) else 0.0
        racing = info["opponent_racing"] and info["ds"] >= -cfg.side_max_behind_m
        forfeit = expected_forfeit(info)
        expected = {
            "pass": cfg.c_pass * (passing + forfeit),
            "stay": (info["s"] - prev["s"]) + cfg.c_stay * staying,
            "left": passing + forfeit + ((min(info["de"], cfg.side_cap_m) + cfg.c_margin) if racing else 0.0),
            "right": passing + forfeit + ((min(-info["de"], cfg.side_cap_m) + cfg.c_margin) if racing else 0.0),
        }[intent]
        assert reward == pytest.approx(info["reward_terms"]["task"] + expected, abs=1e-9)


def test_a_parked_left_driver_stops_earning_its_side_bias_when_the_opponent_finishes(straight):
    # the side bias regardless of the gap (side_max_behind_m has its own test), so only the
    # opponent's finish ends it
    env = RaceEnv(straight, intent="left", env_config=EnvConfig(time_limit_s=40.0),
                  reward_config=RewardConfig(side_max_behind_m=None))
    obs, info = env.reset(seed=0, options={"ego_e": 5.0})  # parked well left of the opponent
    racing, finished = [], []
    window = RewardConfig().pass_window_m
    names = env.observation_names
    for _ in range(400):
        prev = info
        obs, reward, terminated, truncated, info = env.step(np.array([0.0, -1.0]))
        o = dict(zip(names, obs))
        if not info["opponent_racing"]:  # gone from the track: shown far ahead, not alongside
            assert (o["opp_racing"], o["opp_dx"], o["opp_dy"], o["dspeed"]) == (0.0, FAR_AHEAD_M, 0.0, 0.0)
        inside = abs(info["ds"]) <= window or abs(prev["ds"]) <= window
        passing = info["ds"] - prev["ds"] if inside else 0.0
        (racing if info["opponent_racing"] else finished).append(reward - passing)
        if terminated or truncated:
            break
    assert truncated and racing and finished
    assert min(racing) > 0.3  # left of the opponent while it races: de + 0.3 per step
    assert max(abs(r) for r in finished) < 1e-9  # afterwards only the passing term


def test_seeded_reset_is_reproducible(hairpin):
    replays = [parked_opponent(hairpin, 200.0 + 10 * i, 0.0) for i in range(5)]
    a, b = RaceEnv(hairpin, replays=replays), RaceEnv(hairpin, replays=replays)
    picks = [a.reset(seed=s)[1]["replay"] for s in range(10)]
    assert picks == [b.reset(seed=s)[1]["replay"] for s in range(10)]
    assert len(set(picks)) > 1
    policy = lambda o: np.array([0.1 * math.sin(o[0]), 0.4])  # noqa: E731
    ia, _, _, _ = run(a, policy, seed=7)
    ib, _, _, _ = run(b, policy, seed=7)
    assert [i["s"] for i in ia] == [i["s"] for i in ib]


def test_climb_on_the_hairpin_is_slower_than_flat(hairpin):
    """The grade force reaches the car: coasting uphill loses speed faster than downhill."""
    env = RaceEnv(hairpin)
    grade = hairpin.grade
    up_s = float(hairpin.s[np.argmax(grade)])
    down_s = float(hairpin.s[np.argmin(grade)])
    speeds = {}
    for name, s in (("up", up_s), ("down", down_s)):
        env.reset(seed=0, options={"ego_s": s - 10.0, "ego_e": 0.0, "start_speed": 15.0})
        for _ in range(10):
            *_, info = env.step(np.array([0.0, 0.0]))
        speeds[name] = info["speed"]
    assert speeds["up"] < speeds["down"] - 1.0


def test_shared_control_blends_and_shows_partner_actions(straight):
    seen = []

    def human(obs):
        seen.append(obs[-2:].copy())
        return np.array([0.6, 0.7])

    env = SharedControl(RaceEnv(straight, intent="pass"), human)
    obs, _ = env.reset(seed=0)
    obs, _, _, _, info = env.step(np.array([0.7, -0.2]))
    np.testing.assert_allclose(info["applied_action"], blend([0.6, 0.7], [0.7, -0.2]))
    np.testing.assert_allclose(info["applied_action"], [1.0, 0.5], atol=1e-6)
    np.testing.assert_allclose(obs[-2:], [0.6, 0.7])           # assistant sees the human's action
    env.step(np.array([0.0, 0.0]))
    np.testing.assert_allclose(seen[1], [0.7, -0.2], atol=1e-6)  # human saw the assistant's previous action
    np.testing.assert_allclose(seen[0], [0.0, 0.0])


def test_vector_env_steps_many_envs(straight):
    envs = make_vector_env(3, track=straight, intent="pass")
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (3, envs.single_observation_space.shape[0])
    for _ in range(5):
        obs, rewards, term, trunc, infos = envs.step(np.tile([0.0, 0.5], (3, 1)).astype(np.float32))
    assert rewards.shape == (3,) and np.all(np.isfinite(rewards))
    assert np.all(infos["s"] > straight.start_grid.ego.s)
    envs.close()


def test_render_rgb_array(straight):
    env = RaceEnv(straight, render_mode="rgb_array", env_config=EnvConfig(render_width=96, render_height=64))
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (64, 96, 3) and img.dtype == np.uint8
    assert img.std() > 10  # road, grass and cars, not a blank frame
    red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
    assert red.any()  # the ego car is in view


def test_record_episodes_round_trip(straight, tmp_path):
    env = RecordEpisodes(RaceEnv(straight, intent="left"), tmp_path, metadata={"run": "test"})
    infos, *_ = run(env, lambda o: np.array([0.02, 0.9]))
    env.close()
    assert len(env.paths) == 1
    ep = read_episode(env.paths[0])
    assert ep.metadata["run"] == "test" and ep.metadata["intent"] == "left"
    assert ep.metadata["outcome"]["finished"] == infos[-1]["finished"]
    np.testing.assert_allclose(ep.state["ego"]["s"], [i["s"] for i in infos])
    np.testing.assert_allclose(ep.state["ego"]["reward_terms.left"][1:], [i["reward_terms"]["left"] for i in infos[1:]])
    assert ep.poses["ego"].shape == (len(infos), 4) and "opponent" in ep.poses


def moving_opponent(track, speed: float, steps: int) -> OpponentReplay:
    """An opponent driving the centreline from its grid slot at a constant speed."""
    s = track.start_grid.opponent.s + speed * 0.1 * np.arange(steps)
    e = np.full(steps, track.start_grid.opponent.e)
    xyz = np.array([track.from_frenet(float(si), float(ei)) for si, ei in zip(s, e)])
    yaw = np.array([track.heading_at(float(si)) for si in s])
    return OpponentReplay(t=np.arange(steps) * 0.1, x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], yaw=yaw,
                          speed=np.full(steps, speed), s=s, e=e)


def test_a_start_further_along_the_race_keeps_the_grid_gap_and_the_clock(hairpin):
    """`start_step` k: the opponent where its replay is after k steps, the ego the grid's gap
    behind it at the opponent's speed, k steps less time left; `start_spread` draws k from the
    seeded generator (0: the grid start, and the same stream of draws); bad values are refused."""
    grid = hairpin.start_grid
    replays = [moving_opponent(hairpin, 25.0, 300)]
    env = RaceEnv(hairpin, replays=replays, env_config=EnvConfig(time_limit_s=40.0))
    names = env.observation_names
    grid_obs, grid_info = env.reset(seed=3)
    obs, info = env.reset(seed=3, options={"start_step": 120})
    assert info["opponent_s"] == pytest.approx(grid.opponent.s + 25.0 * 12.0)
    assert info["s"] == pytest.approx(info["opponent_s"] - (grid.opponent.s - grid.ego.s), abs=0.05)
    assert info["speed"] == pytest.approx(25.0, abs=0.01) and info["t"] == pytest.approx(12.0)
    assert dict(zip(names, obs))["time_left"] == pytest.approx(40.0 - 12.0)
    assert dict(zip(names, obs))["distance"] == pytest.approx(0.0, abs=1e-6) and info["progress"] == pytest.approx(0.0)
    _, _, terminated, truncated, step_info = env.step(np.array([0.0, 0.5]))
    assert not (terminated or truncated) and not step_info["collision"]  # no contact from the jump
    # spread: reproducible per seed, spread over the race, 0 is the grid start
    starts = [env.reset(seed=s, options={"start_spread": 1.0})[1]["t"] for s in range(12)]
    assert starts == [env.reset(seed=s, options={"start_spread": 1.0})[1]["t"] for s in range(12)]
    assert len(set(starts)) > 6 and max(starts) <= 29.9
    np.testing.assert_array_equal(env.reset(seed=3, options={"start_spread": 0.0})[0], grid_obs)
    for bad in ({"start_step": 300}, {"start_step": -1}, {"start_spread": 1.5}):
        with pytest.raises(ValueError, match="start_s"):
            env.reset(seed=0, options=bad)


def test_the_retired_clearance_observation_loads_only_at_its_old_default():
    """`env.observe_clearance` is retired: a stored record with it off loads, on is an error."""
    assert EnvConfig.model_validate({"observe_clearance": False, "clearance_cap_m": 10.0}) == EnvConfig()
    with pytest.raises(ValueError, match="observe_clearance"):
        EnvConfig.model_validate({"observe_clearance": True})
