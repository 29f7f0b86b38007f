"""Does the assistant's own model say that pass and stay drivers want different throttles?
docs/experiments/assistant-policy.md, "The model does not see what the pass intent pays: reward
relabelling (adopted)".

Dream2assist reads the intent (per-step F1 0.90-0.97) and then applies one throttle to every
driver. Either its world model (reward head and dynamics) does not make the reward of a throttle
depend on the intent it reads, or the model does and the actor-critic does not follow it. This
script asks the model. It drives the paper's test humans of the assistant's populations (as
`d2a eval` selects them, the assistant's mode acting), keeps the assistant's posterior model state
at every step and, from each state, imagines `HORIZON` steps twice in the assistant's own world
model: once with the assistant's acceleration held at +1, once at -1 (steering from its actor's
mode, both rollouts on the same random numbers), and sums the predicted rewards r^A (discounted as
the assistant's critic discounts them; continuation from the continue head). The difference,
"throttle gain" = R(+1) - R(-1), is what the model says full throttle is worth over full braking
there. Printed per true intent and gap to the opponent (the stay objective pays for dropping back
only within 50 m of it), beside the acceleration the actor applied.

    python docs/analysis/throttle_sensitivity.py STORE ASSISTANT_CHECKPOINT [EPISODES_PER_HUMAN] [HORIZON]
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from d2a_core.agents.dreamer.agent import PolicyState
from d2a_core.agents.dreamer.latent import Latent
from d2a_core.artifacts import Store
from d2a_core.agents.dreamer.expert import ExpertFilter
from d2a_core.objectives.assistant import AssistantRewardConfig as RewardConfig
from d2a_core.pipelines.evaluate import panel_specs
from d2a_core.training.shared_rollout import HumanDrivers, SharedCollector
from intent_probe import load_under_test  # the sibling script (this folder is on sys.path)
from d2a_core.stored_agents import load_human

ACCEL = 1  # index of the acceleration in the action ([steer, accel])
SAMPLES = 4  # imagined rollouts per state and throttle (their mean is taken)


class RecordingAssistant:
    """The assistant, with `features` returning the whole model state (h, z's indices, z's
    probabilities, flattened), so that the collector's per-step features can be put back into a
    `Latent`."""

    def __init__(self, agent) -> None:
        self._agent = agent

    def __getattr__(self, name):
        return getattr(self._agent, name)

    def features(self, state: PolicyState) -> np.ndarray:
        latent = state.latent
        n = latent.h.shape[0]
        return torch.cat([latent.h.float(), latent.index.float().reshape(n, -1),
                          latent.probs.float().reshape(n, -1)], -1).cpu().numpy()


class GapCollector(SharedCollector):
    """The evaluation's collector, keeping the gap to the opponent (ds, metres, + = ahead) before
    each of the episode's steps in its row (`gaps`)."""

    def _finish(self, i: int):
        gaps = [float(info["ds"]) for info in self._episode[i]["infos"][:-1]]
        row = super()._finish(i)
        row["gaps"] = gaps
        return row


def drive(humans, agents, expert_agents, intents, make_env, assistant, window, reward_config, episodes):
    """The test humans assisted (mode actions), the experts filtering along as in training, so
    that each step's reward terms are the assistant's own reward (r^A, r_hat*(y_hat))."""
    specs = panel_specs(humans, episodes, 0)
    queue = iter(specs)
    envs = [make_env() for _ in range(8)]
    drivers = HumanDrivers(agents, len(envs), explore=False, seed=0)
    experts = [ExpertFilter(e, len(envs), sample=False, seed=k) for k, e in enumerate(expert_agents)]
    try:
        collector = GapCollector(envs, drivers, intents, lambda: next(queue, None), assistant=assistant,
                                 experts=experts, reward_config=reward_config, keep_steps=True, label_field=None,
                                 record_features=lambda spec: True, partner_window=window)
        rows = []
        while not collector.idle:
            rows.extend(collector.step(explore=False, learn=False))
    finally:
        for env in envs:
            env.close()
    return rows


def unpack(features: np.ndarray, like: Latent) -> Latent:
    """Invert `RecordingAssistant.features` for a batch (N, width), shapes taken from `like`."""
    x = torch.as_tensor(features)
    n, deter = x.shape[0], like.h.shape[-1]
    index_width = like.index[0].numel()
    h = x[:, :deter]
    index = x[:, deter:deter + index_width].round().to(like.index.dtype).reshape(n, *like.index.shape[1:])
    probs = x[:, deter + index_width:].reshape(n, *like.probs.shape[1:]).to(like.probs.dtype)
    return Latent(h.to(like.h.dtype), index, probs)


@torch.no_grad()
def imagined_return(agent, start: Latent, accel: float, horizon: int, seed: int) -> torch.Tensor:
    """Discounted sum of predicted rewards over `horizon` imagined steps from `start` (N,),
    steering by the actor's mode and the acceleration held at `accel` (internal units)."""
    wm, actor, c = agent.world_model, agent.behavior.actor, agent.config
    generator = torch.Generator().manual_seed(seed)
    state, total, weight = start, torch.zeros(start.h.shape[0]), torch.ones(start.h.shape[0])
    for _ in range(horizon):
        action = actor.mode(state).float().clone()
        action[:, ACCEL] = accel
        h = wm.rssm.step(state, action)
        state = wm.rssm.sample_prior(h, wm.rssm.uniform((h.shape[0],), generator, h.device))
        total += weight * wm.reward(state).float()
        weight = weight * c.discount * (wm.continue_prob(state) > 0.5).float()
    return total


def main(store_path: str, ref: str, episodes: int = 4, horizon: int = 15) -> None:
    store = Store(store_path)
    under = load_under_test(store, ref)
    art, intents, humans, assistant, window = under.art, under.intents, under.humans, under.assistant, under.window
    agents = [load_human(store, h.id, under.obs_space, under.act_space, "cpu") for h in humans]
    expert_agents = [load_human(store, pop["expert"], under.obs_space, under.act_space, "cpu")
                     for _, pop in under.populations]
    rows = drive(humans, agents, expert_agents, intents, under.make_env, RecordingAssistant(assistant), window,
                 RewardConfig(**art.config["assistant"]["reward"]), episodes)
    logs = [r.pop("steps_log") for r in rows]

    like = assistant.initial_state(1).latent
    x = np.concatenate([r["features"] for r in rows])
    label = np.concatenate([np.full(len(r["features"]), r["label"]) for r in rows])
    gap = np.concatenate([np.asarray(r["gaps"]) for r in rows])
    applied_accel = np.concatenate([np.asarray(log["assistant_action"], np.float32).reshape(-1, 2)[:, ACCEL]
                                    for log in logs])
    human_accel = np.concatenate([np.asarray(log["human_action"], np.float32).reshape(-1, 2)[:, ACCEL]
                                  for log in logs])
    gains = []
    for start in range(0, len(x), 1024):
        latent = unpack(x[start:start + 1024], like)
        up = torch.stack([imagined_return(assistant, latent, 1.0, horizon, 7 + k) for k in range(SAMPLES)]).mean(0)
        down = torch.stack([imagined_return(assistant, latent, -1.0, horizon, 7 + k) for k in range(SAMPLES)]).mean(0)
        gains.append((up - down).numpy())
    gain = np.concatenate(gains)

    # what the reward head predicts on arriving at each real state, against the real r^A there
    with torch.no_grad():
        predicted = np.concatenate([assistant.world_model.reward(unpack(x[start:start + 4096], like)).float().numpy()
                                    for start in range(0, len(x), 4096)])
    step_rows = []  # per step t < T-1 of every episode: label, y_hat, gap, d gap, r*, r^A, predicted r^A
    offset = 0
    for r, log in zip(rows, logs):
        n = len(r["features"])
        terms = np.asarray(log["terms"], np.float64).reshape(n, -1)
        g = np.asarray(r["gaps"])
        for t in range(n - 1):
            step_rows.append((r["label"], log["y_hat"][t], g[t], g[t + 1] - g[t], terms[t, 2], terms[t, 4],
                              predicted[offset + t + 1]))
        offset += n
    steps = np.array(step_rows)

    print(f"assistant {art.id[:12]} ({art.labels.get('method')}, seed {art.seed}, env step {art.labels.get('env_step')}): "
          f"{len(rows)} episodes, {len(x)} steps, horizon {horizon}")
    print("| true intent | gap to the opponent | steps | throttle gain R(+1) - R(-1): mean, median, share > 0 | assistant accel | human accel |")
    print("|---|---|---|---|---|---|")
    bands = [("any", -np.inf, np.inf), ("> 50 m behind", -np.inf, -50), ("50-0 m behind", -50, 0),
             ("ahead", 0, np.inf)]
    for k, name in enumerate(intents):
        for band, low, high in bands:
            mask = (label == k) & (gap >= low) & (gap < high)
            if not mask.any():
                continue
            g = gain[mask]
            print(f"| {name} | {band} | {mask.sum()} | {g.mean():+.2f}, {np.median(g):+.2f}, {np.mean(g > 0):.2f} | "
                  f"{applied_accel[mask].mean():+.2f} | {human_accel[mask].mean():+.2f} |")

    print()
    print("Within 50 m behind the opponent, correctly inferred steps: slope of each reward on the step's gap change "
          "(per metre gained on the opponent; the pass objective pays +10, the stay objective -2 plus progress)")
    print("| true intent | steps | r_hat*(y_hat) (the expert's model) | r^A (real) | r^A as the assistant's reward head predicts it |")
    print("|---|---|---|---|---|")
    for k, name in enumerate(intents):
        m = (steps[:, 0] == k) & (steps[:, 1] == k) & (steps[:, 2] >= -50) & (steps[:, 2] < 0)
        if m.sum() < 10:
            continue
        slopes = [np.polyfit(steps[m, 3], steps[m, col], 1)[0] for col in (4, 5, 6)]
        print(f"| {name} | {int(m.sum())} | " + " | ".join(f"{v:+.2f}" for v in slopes) + " |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(int(a) for a in sys.argv[3:5]))
