"""What the stay and pass objectives pay for canonical behaviours, and what an assistant pays to
impose them on a driver who keeps the throttle down.

The assistant is paid the expert's reward of the inferred intent minus ||a_A|| per step (paper eq.
6 with alpha_a = 0). This drives the env with simple scripted controllers (steering to a lateral
target, throttle to a gap target behind the opponent, or flat out beside it) over the env seeds
of evaluation, and prints per behaviour: the env's exact return under the stay and the pass
objectives (r^task + r^y, as the experts were trained), whether the car finished, ever got ahead,
collided, and the intervention sum(||a_A||) an assistant would pay to impose that behaviour on a
human pressing full throttle (a_H accel = +1, the human's steering kept: a_A = (0, u - 1) for an
executed throttle u). The difference between two behaviours' stay returns, against the
difference of their intervention sums, is what the assistant's reward says about carrying a
pass-like stay driver past the opponent or holding it back.

    python docs/analysis/stay_objective.py STORE HUMAN_ID [EPISODES]

HUMAN_ID is any stored driver of the track (only its env settings are used).
"""

from __future__ import annotations

import sys

import numpy as np

from d2a_core import api

BEHAVIOURS = {  # name: (gap target behind the opponent in m, or None for flat out; lateral target in m)
    "flat out, pass on the left": (None, 4.5),
    "follow 5 m behind": (5.0, 0.0),
    "follow 15 m behind (the grid gap)": (15.0, 0.0),
    "drop back to 50 m, then follow": (50.0, 0.0),
}


def controller(obs: np.ndarray, names: list[str], gap: float | None, lateral: float) -> tuple[float, float]:
    """[steer, accel]: steer toward `lateral` (P on offset and heading), throttle toward `gap`."""
    o = dict(zip(names, obs))
    heading = np.arctan2(o["sin_track_yaw"], o["cos_track_yaw"])  # the car's heading relative to the road
    # a heading toward the lateral target (at most 0.1 rad), then steer to that heading: the
    # car's steering is speed-sensitive, so gains of a low-speed controller spin it at 30 m/s
    want = float(np.clip(0.04 * (lateral - o["e"]), -0.1, 0.1))
    steer = float(np.clip(2.0 * (want - heading), -1, 1))
    if gap is None or o["opp_racing"] < 0.5:
        return steer, 1.0
    # ds < 0 behind; close to -gap, damped by the closing speed (dspeed = opponent minus ego)
    accel = float(np.clip(0.3 * (-gap - o["ds"]) + 0.6 * o["dspeed"], -1, 1))
    return steer, accel


def run(env_stay, env_pass, names, gap, lateral, seed) -> dict[str, float]:
    out = {}
    for label, env in (("stay", env_stay), ("pass", env_pass)):
        obs, _ = env.reset(seed=seed)
        total, interv, ahead, done, info = 0.0, 0.0, False, False, {}
        while not done:
            steer, accel = controller(obs, names, gap, lateral)
            obs, reward, terminated, truncated, info = env.step(np.array([steer, accel], np.float32))
            total += reward
            interv += abs(min(accel, 1.0) - 1.0)
            ahead = ahead or dict(zip(names, obs))["ds"] > 0
            done = terminated or truncated
        out[f"return_{label}"] = total
        if label == "stay":
            out.update(interv=interv, ahead=float(ahead), finished=float(bool(info.get("finished"))),
                       collision=float(bool(info.get("collision"))))
    return out


def main(argv: list[str]) -> None:
    store, human_id = argv[0], argv[1]
    episodes = int(argv[2]) if len(argv) > 2 else 10
    human = api.load(human_id, store)
    env_stay, env_pass = human.make_env(intent="stay"), human.make_env(intent="pass")
    names = list(env_stay.unwrapped.observation_names)
    print(f"{'behaviour':38s} {'stay return':>12s} {'pass return':>12s} {'finished':>8s} {'ahead':>6s} "
          f"{'collided':>8s} {'sum ||a_A|| vs full throttle':>28s}")
    for name, (gap, lateral) in BEHAVIOURS.items():
        rows = [run(env_stay, env_pass, names, gap, lateral, 50_000_000 + k) for k in range(episodes)]
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        print(f"{name:38s} {mean['return_stay']:12.1f} {mean['return_pass']:12.1f} {mean['finished']:8.2f} "
              f"{mean['ahead']:6.2f} {mean['collision']:8.2f} {mean['interv']:28.1f}")


if __name__ == "__main__":
    main(sys.argv[1:])
