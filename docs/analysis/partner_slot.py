"""Do the synthetic drivers react to what their partner slot shows?

Drivers train alone, so the last two entries of their observation (the partner's last action)
are always zero in training; under shared control they show the assistant's action. If a
driver's policy depended on that slot, an assistant could change the driver's own behaviour
through it, an effect no assistant reward accounts for. Here each driver drives alone (the car
executes only its own action) while its partner slot shows:

- `alone`: zeros, as in its training;
- `cancel`: what a taking-over assistant sends (steering the negative of the driver's last,
  throttle +0.4; docs/experiments/assistant-policy.md, "One action for every driver");
- `brake`: a constant brake (0, -0.5);
- `noise`: uniform noise in [-1, 1] on both controls.

Per driver and slot content: mean progress (m), the share of episodes never ahead of the
opponent, the share that ends ahead, and the mean throttle. Drivers are the checkpoints at the
env steps given (default: every checkpoint) and each population's expert.

    python docs/analysis/partner_slot.py STORE POPULATION [POPULATION ...] [--episodes 8] [--steps 8000 12000]
"""

from __future__ import annotations

import argparse

import numpy as np

from d2a_core import api
from d2a_core.artifacts import Store

SLOTS = ("alone", "cancel", "brake", "noise")


def slot_content(kind: str, last_action: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
    if kind == "alone":
        return None
    if kind == "cancel":
        return np.array([-last_action[0], 0.4], np.float32)
    if kind == "brake":
        return np.array([0.0, -0.5], np.float32)
    return rng.uniform(-1.0, 1.0, 2).astype(np.float32)


def episode(env, driver: api.Driver, kind: str, seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    driver.reset()
    last, done, ever_ahead, throttle = np.zeros(2, np.float32), False, False, []
    while not done:
        action = driver.act(api.human_view(obs, slot_content(kind, last, rng)))
        driver.executed(action)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        ever_ahead |= info["ds"] > 0
        throttle.append(float(action[1]))
        last = action
    return {"progress": float(info["progress"]), "never_ahead": float(not ever_ahead),
            "ends_ahead": float(info["ds"] > 0), "throttle": float(np.mean(throttle))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store")
    parser.add_argument("populations", nargs="+")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--steps", type=int, nargs="*", help="env steps of the checkpoints (default: all)")
    args = parser.parse_args()
    store = Store(args.store)
    print("| intent | env step | partner slot | progress m | never ahead | ends ahead | throttle |")
    print("|---|---|---|---|---|---|---|")
    for ref in args.populations:
        population = store.read_json(store.resolve(ref), "population.json")
        for checkpoint in population["checkpoints"]:
            chosen = args.steps is None or checkpoint["env_step"] in args.steps
            if not chosen and checkpoint["id"] != population["expert"]:
                continue
            driver = api.Driver(store, store.get(checkpoint["id"]))
            env = driver.make_env()
            for kind in SLOTS:
                rows = [episode(env, driver, kind, seed) for seed in range(args.episodes)]
                mean = {k: np.mean([r[k] for r in rows]) for k in rows[0]}
                print(f"| {population['intent']} | {checkpoint['env_step'] // 1000}k | {kind} | {mean['progress']:.0f} "
                      f"| {mean['never_ahead']:.2f} | {mean['ends_ahead']:.2f} | {mean['throttle']:+.2f} |", flush=True)
            env.close()


if __name__ == "__main__":
    main()
