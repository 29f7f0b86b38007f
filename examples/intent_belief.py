"""Plot what a stored assistant believes about its driver's intent over one episode.

    python examples/intent_belief.py --store artifacts \
        --assistant assistants/straightaway/pass-stay/dream2assist/seed0 --out intent_belief.png

For each intent of the assistant's pair, the expert of that intent's population drives one
episode with the assistant beside it (`--human` names other drivers instead, one per intent).
Top: p(intent) over time, one line per intent of the pair (the driver's true intent drawn
solid); bottom: the gap to the opponent and how hard the assistant intervenes (||a_A||).
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from d2a_core import api  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", default="artifacts")
    parser.add_argument("--assistant", default="assistants/straightaway/pass-stay/dream2assist/seed0")
    parser.add_argument("--human", action="append", help="driver per intent (default: each population's expert)")
    parser.add_argument("--seed", type=int, default=0, help="env seed of the episodes")
    parser.add_argument("--out", default="intent_belief.png")
    args = parser.parse_args()

    assistant = api.load(args.assistant, store=args.store)
    track = assistant.artifact.labels["track"]
    humans = args.human or [f"humans/{track}/{intent}/expert" for intent in assistant.intents]
    fig, axes = plt.subplots(2, len(humans), figsize=(5 * len(humans), 6), sharex="col", squeeze=False)
    for column, ref in enumerate(humans):
        human = api.load(ref, store=args.store)
        episode = api.drive(assistant.make_env(), human, assistant, seed=args.seed)
        t = episode["t"]
        top, bottom = axes[0, column], axes[1, column]
        for k, intent in enumerate(episode["intents"]):
            top.plot(t, episode["intent_probs"][:, k], label=f"p({intent})",
                     linestyle="-" if intent == human.intent else "--")
        top.set_ylim(-0.02, 1.02)
        top.set_title(f"{human.intent} driver {human.id[:8]} ({human.env_step} env steps)")
        top.legend(loc="best")
        bottom.plot(t, episode["gap_m"], label="gap to opponent (m)")
        bottom.axhline(0.0, color="grey", linewidth=0.5)
        bottom.set_xlabel("t (s)")
        twin = bottom.twinx()
        twin.plot(t, np.linalg.norm(episode["assistant_action"], axis=1), color="tab:red", label="||a_A||")
        twin.set_ylabel("||a_A||")
        bottom.legend(loc="upper left")
        twin.legend(loc="upper right")
        info = episode["info"]
        outcome = "finished" if info["finished"] else "collision" if info["collision"] else "off track" \
            if info["off_track"] else "time limit"
        print(f"{human.intent} driver {human.id[:12]}: {outcome}, mean p({human.intent}) "
              f"{episode['intent_probs'][:, episode['intents'].index(human.intent)].mean():.2f}")
    fig.suptitle(f"{assistant.method.name} assistant {assistant.id[:12]}")
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
