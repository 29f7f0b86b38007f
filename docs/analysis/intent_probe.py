"""Is the intent in the assistant's model state? docs/experiments/intent-estimate.md, "Is the
intent in the model state? A probe".

The intent head reads the assistant's model state and reaches per-step F1 0.7-0.8 on the panel,
where a classifier on the human's 16 previous actions reaches 0.98 (intent_from_human_actions.py).
This script separates the two possible losses: the state not carrying the intent, or the head not
reading it. It drives the paper's test humans of the assistant's own populations (imperfect 1-5
and the near-perfect ones, `d2a eval`'s selection) with the assistant checkpoint, records the
deterministic model state h at every step, and scores classifiers fitted on h (a linear probe and
gradient boosting, scikit-learn) by per-step macro F1 under 5-fold cross-validation grouped by
episode (other episodes of the same humans) and by human (humans the probe never saw), beside the
head's own estimate on the same steps; the same classifiers on the human's previous actions
(as many as the assistant's partner window holds) give the reference.

    python docs/analysis/intent_probe.py STORE ASSISTANT_CHECKPOINT [EPISODES_PER_HUMAN]
"""

from __future__ import annotations

import itertools
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.linear_model import LogisticRegression
from sklearn.metrics import f1_score
from sklearn.model_selection import GroupKFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from d2a_core.artifacts import Store
from d2a_core.config.schema import Config
from d2a_core.evaluation.paired import select_humans
from d2a_core.pipelines.evaluate import panel_specs, run_specs
from d2a_core.run_inputs import ENV_SECTIONS, load_populations, load_track_bundle, parse_pair
from d2a_core.sim.race_env import RaceEnv
from d2a_core.stored_agents import load_assistant, load_human
from intent_from_human_actions import previous_actions  # the sibling script (this folder is on sys.path)


@dataclass
class AssistantUnderTest:
    """An assistant checkpoint loaded with what driving its test humans needs."""

    art: Any
    intents: tuple[str, ...]
    populations: list  # (id, population.json) per intent, in pair order
    humans: list  # `d2a eval`'s test humans of both populations
    make_env: Callable[[], RaceEnv]
    assistant: Any
    window: int  # the assistant's partner window
    obs_space: Any
    act_space: Any


def load_under_test(store: Store, ref: str) -> AssistantUnderTest:
    """The assistant `ref`, its populations (its inputs), the paper's test humans of them and an
    env factory with the config it was trained with."""
    art = store.get(ref)
    intents = parse_pair(art.labels["pair"])
    cfg = Config.model_validate({k: art.config[k] for k in ENV_SECTIONS})
    bundle = load_track_bundle(store, art.labels["track"], cfg.env.dt)
    population_ids = [i for i in art.inputs if store.get(i).kind == "population"]
    by_intent = {store.read_json(i, "population.json")["intent"]: i for i in population_ids}
    populations = load_populations(store, bundle, intents, [by_intent[i] for i in intents])
    humans = [h for label, (_, pop) in enumerate(populations) for h in select_humans(pop, intents[label], label)]

    def make_env() -> RaceEnv:
        return bundle.env(cfg)

    probe = make_env()
    obs_space, act_space = probe.observation_space, probe.action_space
    probe.close()
    assistant, _, _, window = load_assistant(store, art.id, obs_space, act_space)
    return AssistantUnderTest(art, tuple(intents), populations, humans, make_env, assistant, window, obs_space,
                              act_space)


def drive(store: Store, ref: str, episodes: int) -> tuple[list[dict], list, list[dict], int]:
    """The assistant's test humans, assisted, with h recorded at every step: (rows, humans, step
    logs, the assistant's partner window)."""
    under = load_under_test(store, ref)
    humans, window = under.humans, under.window
    agents = {h.id: load_human(store, h.id, under.obs_space, under.act_space, "cpu") for h in humans}
    with tempfile.TemporaryDirectory(prefix="d2a-probe-") as tmp:
        rows, logs = run_specs(panel_specs(humans, episodes, 0), [agents[h.id] for h in humans], under.intents,
                               under.make_env, 8, Path(tmp), under.assistant, record_features=lambda spec: True,
                               partner_window=window)
    return rows, humans, logs, window


def main(store_path: str, ref: str, episodes: int = 10) -> None:
    rows, humans, logs, window = drive(Store(store_path), ref, episodes)
    x = np.concatenate([r["features"] for r in rows])
    y = np.concatenate([np.full(len(r["features"]), r["label"]) for r in rows])
    by_episode = np.concatenate([np.full(len(r["features"]), k) for k, r in enumerate(rows)])
    by_human = np.concatenate([np.full(len(r["features"]), r["human"]) for r in rows])
    y_hat = np.concatenate([np.asarray(log["y_hat"]) for log in logs])
    print(f"{len(rows)} episodes, {len(humans)} humans, {len(y)} steps; h has {x.shape[1]} units")
    print(f"the assistant's own intent head: F1 {f1_score(y, y_hat, average='macro'):.3f}")
    probes = {"linear probe (logistic regression)": lambda: make_pipeline(StandardScaler(),
                                                                          LogisticRegression(max_iter=2000)),
              "gradient boosting": lambda: HistGradientBoostingClassifier(max_iter=200, random_state=0)}
    inputs = {"h": x, f"the human's {window} previous actions": np.concatenate(
        [previous_actions(np.asarray(log["human_action"], np.float32).reshape(-1, 2), window) for log in logs])}
    for (name, make), (input_name, features) in itertools.product(probes.items(), inputs.items()):
        scores = []
        for groups in (by_episode, by_human):
            pred = np.zeros_like(y)
            folds = GroupKFold(n_splits=min(5, len(np.unique(groups))))
            for train, test in folds.split(features, y, groups):
                pred[test] = make().fit(features[train], y[train]).predict(features[test])
            scores.append(f1_score(y, pred, average="macro"))
        print(f"{name} on {input_name}: F1 {scores[0]:.3f} on other episodes of the same humans, "
              f"{scores[1]:.3f} on humans it never saw")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(int(a) for a in sys.argv[3:4]))
