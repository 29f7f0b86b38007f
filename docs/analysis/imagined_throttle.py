"""Does the assistant's own world model say that more throttle behind the opponent pays, for a
driver it reads as stay? Separates a model that misjudges the stay objective from an actor that
does not follow its model.

Drives assisted episodes of the chosen humans (mode actions, as evaluation does). At every step
where the car is behind the opponent and closing in (ds in [-25, -3] m), it takes the assistant's
model state and imagines `--horizon` steps in its world model with the actor's own action plus
a throttle offset (steer unchanged), for each offset; each offset's rollout is repeated
`--samples` times (the prior's latents are sampled). Per human and offset: the mean imagined
return (rewards of the assistant's reward head, discounted, plus the critic's value at the end),
relative to the actor's own action (offset 0), and the gap to the opponent the decoder predicts
at the end. Beside them: the actor's own throttle at those steps, and the share of them read as
the human's intent.

An actor that follows its model picks the offset whose return is highest, so the best offset
is about 0. A best offset well below 0 for stay drivers means the model says "slow down" and the
actor does not; a best offset at or above 0 means the model itself pays for speeding up.

    python docs/analysis/imagined_throttle.py STORE ASSISTANT HUMAN [HUMAN ...] [--episodes 3]
"""

from __future__ import annotations

import numpy as np
import torch

from d2a_core import api
from d2a_core.agents.dreamer.distributions import symexp
from d2a_core.sim.race_env import OPPONENT_FIELDS, PARTNER_FIELDS
from assisted_steps import assisted_steps, probe_parser  # the sibling module (this folder is on sys.path)

OFFSETS = (-0.6, -0.3, -0.15, 0.0, 0.15, 0.3)
CLOSING_M = (-25.0, -3.0)


@torch.no_grad()
def imagined(agent, latent, horizon: int, samples: int, ds_index: int, generator: torch.Generator) -> dict:
    """Imagined return and end gap per throttle offset from one model state (leading shape (1,))."""
    wm, behavior, c = agent.world_model, agent.behavior, agent.config
    offsets = torch.tensor(OFFSETS).repeat_interleave(samples)
    n = offsets.numel()
    start = latent.select(torch.zeros(n, dtype=torch.long))
    shift = torch.stack([torch.zeros(n), offsets], -1)

    def policy(state, first):
        return (behavior.actor.mode(state.detach()) + shift).clamp(-1.0, 1.0), {}

    rollout = wm.rssm.imagine(policy, start, horizon, generator)
    rewards = torch.stack([wm.reward(s).reshape(n) for s in rollout.states[1:]])
    conts = torch.stack([(wm.continue_prob(s).reshape(n) > 0.5).float() for s in rollout.states[1:]])
    value = behavior.twohot.mean(behavior.critic(rollout.states[-1])).reshape(n)
    weight = torch.cumprod(torch.cat([torch.ones(1, n), c.discount * conts[:-1]]), 0)
    ret = (weight * rewards).sum(0) + weight[-1] * c.discount * conts[-1] * value
    ds_end = symexp(wm.decoder(rollout.states[-1]))[:, ds_index].reshape(n)
    return {"return": ret.view(len(OFFSETS), samples).mean(1).numpy(),
            "ds_end": ds_end.view(len(OFFSETS), samples).mean(1).numpy()}


def probe_human(assistant: api.Assistant, human: api.Driver, episodes: int, horizon: int, samples: int) -> dict:
    size = assistant.observation_space.shape[0]
    # the opponent block sits before the partner slot at the end of the observation
    ds_index = size - len(PARTNER_FIELDS) - len(OPPONENT_FIELDS) + OPPONENT_FIELDS.index("ds")
    generator = torch.Generator().manual_seed(0)
    returns, ends, throttles, read_as = [], [], [], []
    for obs, a_assist in assisted_steps(assistant, human, episodes):
        ds = float(obs[ds_index])
        if CLOSING_M[0] <= ds <= CLOSING_M[1]:
            out = imagined(assistant._agent, assistant._state.latent, horizon, samples, ds_index, generator)
            returns.append(out["return"] - out["return"][OFFSETS.index(0.0)])
            ends.append(out["ds_end"])
            throttles.append(float(a_assist[1]))
            belief = assistant.intent() or {}
            read_as.append(float(max(belief, key=belief.get) == human.intent) if belief else np.nan)
    if not returns:
        return {}
    mean_return = np.mean(returns, 0)
    return {"steps": len(returns), "return_vs_own": mean_return, "best_offset": OFFSETS[int(np.argmax(mean_return))],
            "ds_end": np.mean(ends, 0), "throttle": float(np.mean(throttles)), "read_as_intent": float(np.nanmean(read_as))}


def main() -> None:
    parser = probe_parser(__doc__.split("\n\n")[0], episodes=3)
    parser.add_argument("--horizon", type=int, default=15)
    args = parser.parse_args()
    assistant = api.load(args.assistant, store=args.store)
    offsets = " | ".join(f"{o:+.2f}" for o in OFFSETS)
    print(f"| human | steps | actor's throttle | read as its intent | return vs own action, offset {offsets} | best "
          f"| predicted ds at the end, offset {offsets} |")
    print("|---|---|---|---|---|---|---|")
    for ref in args.humans:
        human = api.load(ref, store=args.store)
        row = probe_human(assistant, human, args.episodes, args.horizon, args.samples)
        if not row:
            print(f"| {human.intent} {human.env_step // 1000}k | 0 | | | | | |")
            continue
        print(f"| {human.intent} {human.env_step // 1000}k | {row['steps']} | {row['throttle']:+.2f} "
              f"| {row['read_as_intent']:.2f} | {' / '.join(f'{v:+.2f}' for v in row['return_vs_own'])} "
              f"| {row['best_offset']:+.2f} | {' / '.join(f'{v:+.1f}' for v in row['ds_end'])} |", flush=True)


if __name__ == "__main__":
    main()
