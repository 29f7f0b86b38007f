"""What the assistant's world model expects at the finish line, where assisted cars that arrive
fast swerve off the left edge instead of crossing it.

Drives assisted episodes of the chosen humans as evaluation does (mode actions, env seeds
50,000 + k). At every step past `--from` metres it imagines one step from the assistant's model
state with three actions: the actor's own, the same with steering zeroed (straight on), and the
same with full throttle and no steering; `--samples` prior draws each, the same random numbers for
the three. It prints, per human, the mean over those steps of the predicted continue probability
(1 - P(episode ends)) and reward after each action, beside what the env did after the actor's
action (how the episode ended and where). A model that knows the line ends the episode predicts
a low continue for straight on at the last step; one that does not see the edge predicts a high
continue for the swerve that leaves the road.

    python docs/analysis/finish_swerve.py STORE ASSISTANT HUMAN [HUMAN ...] [--episodes 3] [--from 330]
"""

from __future__ import annotations

import numpy as np
import torch

from d2a_core import api
from d2a_core.sim.shared_control import blend
from assisted_steps import probe_parser  # the sibling module (this folder is on sys.path)


@torch.no_grad()
def one_step(agent, latent, action: np.ndarray, samples: int, generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(continue probability, reward) predicted after one step with: the action, the action with
    steering zeroed, full throttle straight on."""
    wm = agent.world_model
    own = torch.as_tensor(action, dtype=torch.float32)
    candidates = torch.stack([own, torch.stack([torch.zeros(()), own[1]]), torch.tensor([0.0, 1.0])])
    start = latent.select(torch.zeros(len(candidates) * samples, dtype=torch.long))
    acts = candidates.repeat_interleave(samples, 0)
    rollout = wm.rssm.imagine(lambda state, first: (acts, {}), start, 1, generator)
    after = rollout.states[1]
    cont = wm.continue_prob(after).reshape(len(candidates), samples).mean(1).numpy()
    reward = wm.reward(after).reshape(len(candidates), samples).mean(1).numpy()
    return cont, reward


def probe(assistant: api.Assistant, human: api.Driver, episodes: int, start_m: float, samples: int) -> list[dict]:
    generator = torch.Generator().manual_seed(0)
    env = assistant.make_env(human.intent)
    rows = []
    try:
        for seed in range(episodes):
            obs, info = env.reset(seed=50_000 + seed)
            human.reset()
            assistant.reset()
            a_assist, done, steps = np.zeros(2, np.float32), False, []
            while not done:
                a_human = human.act(api.human_view(obs, a_assist))
                a_assist = assistant.act(obs)
                s = float(env.unwrapped._s)
                if s >= start_m:
                    cont, reward = one_step(assistant._agent, assistant._state.latent, a_assist, samples, generator)
                    steps.append({"s": s, "cont": cont, "reward": reward, "steer": float(a_assist[0])})
                executed = blend(a_human, a_assist)
                human.executed(executed)
                env.unwrapped.set_partner_action(a_human)
                obs, _, terminated, truncated, info = env.step(executed)
                done = terminated or truncated
            ended = "collision" if info.get("collision") else "off track" if info.get("off_track") else \
                "finish" if info.get("finished") else "time limit"
            rows.append({"seed": seed, "ended": ended, "s_end": float(env.unwrapped._s), "steps": steps})
    finally:
        env.close()
    return rows


def main() -> None:
    parser = probe_parser(__doc__.split("\n\n")[0], episodes=3)
    parser.add_argument("--from", dest="start_m", type=float, default=330.0, help="probe the steps past this s (m)")
    args = parser.parse_args()
    assistant = api.load(args.assistant, store=args.store)
    print(f"assistant {assistant.id[:12]}")
    print("| human | episode: end (s) | steps probed | actor's steer, last 3 | continue: own / straight / flat out, "
          "last step | reward: own / straight / flat out, last step | continue, own, mean over probed |")
    print("|---|---|---|---|---|---|---|")
    for ref in args.humans:
        human = api.load(ref, store=args.store)
        for row in probe(assistant, human, args.episodes, args.start_m, args.samples):
            st = row["steps"]
            if not st:
                print(f"| {human.intent} {human.env_step // 1000}k | {row['ended']} ({row['s_end']:.0f} m) | 0 | | | | |")
                continue
            last = st[-1]
            print(f"| {human.intent} {human.env_step // 1000}k | {row['ended']} ({row['s_end']:.0f} m) | {len(st)} "
                  f"| {', '.join(format(x['steer'], '+.2f') for x in st[-3:])} "
                  f"| {' / '.join(f'{c:.2f}' for c in last['cont'])} | {' / '.join(f'{r:+.1f}' for r in last['reward'])} "
                  f"| {np.mean([x['cont'][0] for x in st]):.2f} |", flush=True)


if __name__ == "__main__":
    main()
