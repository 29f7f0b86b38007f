"""Does the assistant's world model see what its intervention costs?

The assistant is charged -w_interv * ||a_A|| at every step (paper eq. 6), a known function of its
own action. DreamerV3 learns every reward term through the reward head, which reads the next
model state; the action reaches that state only through the GRU's input. If the head does not
resolve the charge, the actor's gradient through the dynamics never feels it, and nothing in
imagination asks for a small intervention.

Drives assisted episodes of the chosen humans (mode actions, as evaluation does). At every step
it takes the assistant's model state and imagines one step with three actions: the actor's own
(mode), no intervention (a_A = 0), and the actor's own with steering zeroed; `--samples` prior
draws each (the same random numbers for the three). Per human: the mean ||a_A|| of the actor, the
charge it should see (-w_interv * ||a_A||, the exact difference of the eq.-6 reward between the
own action and no action, all else equal), and the difference of the reward head's predictions
(own action minus no action). A head that sees the charge predicts about the charge; a head that
predicts ~0 makes the intervention free in imagination.

One step of a different action also moves the car a little, so the predicted difference also
holds that step's real effect on the expert's reward (a few tenths at most on the straightaway).

    python docs/analysis/intervention_seen.py STORE ASSISTANT HUMAN [HUMAN ...] [--episodes 2]
"""

from __future__ import annotations

import numpy as np
import torch

from d2a_core import api
from assisted_steps import assisted_steps, probe_parser  # the sibling module (this folder is on sys.path)


@torch.no_grad()
def one_step_rewards(agent, latent, action: np.ndarray, samples: int, generator: torch.Generator) -> np.ndarray:
    """Predicted reward after one step with: the action, no action, the action without steering."""
    wm = agent.world_model
    own = torch.as_tensor(action, dtype=torch.float32)
    candidates = torch.stack([own, torch.zeros_like(own), torch.stack([torch.zeros(()), own[1]])])
    n = candidates.shape[0] * samples
    start = latent.select(torch.zeros(n, dtype=torch.long))
    acts = candidates.repeat_interleave(samples, 0)

    def policy(state, first):
        return acts, {}

    rollout = wm.rssm.imagine(policy, start, 1, generator)
    return wm.reward(rollout.states[1]).reshape(len(candidates), samples).mean(1).numpy()


def probe_human(assistant: api.Assistant, human: api.Driver, episodes: int, samples: int, w_interv: float) -> dict:
    generator = torch.Generator().manual_seed(0)
    norms, steer_norms, predicted, predicted_steer = [], [], [], []
    for _, a_assist in assisted_steps(assistant, human, episodes):
        r = one_step_rewards(assistant._agent, assistant._state.latent, a_assist, samples, generator)
        norms.append(float(np.linalg.norm(a_assist)))
        steer_norms.append(float(np.linalg.norm(a_assist) - abs(a_assist[1])))
        predicted.append(float(r[0] - r[1]))
        predicted_steer.append(float(r[0] - r[2]))
    norms, predicted = np.asarray(norms), np.asarray(predicted)
    slope = float(np.polyfit(norms, predicted, 1)[0]) if norms.std() > 1e-6 else float("nan")
    return {"steps": len(norms), "norm": float(norms.mean()), "charge": -w_interv * float(norms.mean()),
            "predicted": float(predicted.mean()), "slope": slope,
            "steer_charge": -w_interv * float(np.mean(steer_norms)), "predicted_steer": float(np.mean(predicted_steer))}


def main() -> None:
    parser = probe_parser(__doc__.split("\n\n")[0], episodes=2)
    args = parser.parse_args()
    assistant = api.load(args.assistant, store=args.store)
    w_interv = float(assistant.artifact.config["assistant"]["reward"]["w_interv"])
    print(f"assistant {assistant.id[:12]}, w_interv {w_interv:g}")
    print("| human | steps | actor's ‖a_A‖ | charge, exact | predicted: own action − none | slope of predicted on ‖a_A‖ "
          "| steering's share of the charge, exact | predicted: own − steering zeroed |")
    print("|---|---|---|---|---|---|---|---|")
    for ref in args.humans:
        human = api.load(ref, store=args.store)
        row = probe_human(assistant, human, args.episodes, args.samples, w_interv)
        print(f"| {human.intent} {human.env_step // 1000}k | {row['steps']} | {row['norm']:.2f} | {row['charge']:+.2f} "
              f"| {row['predicted']:+.2f} | {row['slope']:+.2f} | {row['steer_charge']:+.2f} "
              f"| {row['predicted_steer']:+.2f} |", flush=True)


if __name__ == "__main__":
    main()
