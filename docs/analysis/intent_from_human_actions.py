"""How much of the intent the human's own actions carry: docs/experiments/intent-estimate.md,
"How much of the intent the human's actions carry".

From the assisted episodes of a `d2a eval` artifact or of an assistant checkpoint's panel (their
`steps.npz`: the human's action at every step), a gradient-boosted classifier (scikit-learn)
predicts the episode's intent at every step from features of the human's actions up to that
step, and is scored by per-step macro F1 under 5-fold cross-validation grouped two ways:
by episode (other episodes of the same humans: the training humans' case) and by human (humans
it never saw: the held-out case). The assistant's own estimate (`y_hat`) on the same steps is
printed beside it, and, for the richest features, each human's accuracy when left out.

    python docs/analysis/intent_from_human_actions.py STORE ARTIFACT_ID
    python docs/analysis/intent_from_human_actions.py STORE FIT_ID SCORE_ID   # fit on one, score another
"""

from __future__ import annotations

import json
import sys

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.metrics import f1_score
from sklearn.model_selection import GroupKFold

from d2a_core.artifacts import Store

WINDOW = 16  # the No-RSSM baseline's window (paper appendix): about 1.5 s


def previous_actions(actions: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Per step t of one episode (T, 2): the human's actions t-window .. t-1, zero before the
    start. The assistant acts in the same step as the human, so this, never a_t, is what it has
    seen with `assistant.partner_window` = window: the fair comparison with its estimate."""
    padded = np.vstack([np.zeros((window, 2), np.float32), actions])
    return np.stack([padded[t:t + window].ravel() for t in range(len(actions))])


def features(actions: np.ndarray) -> dict[str, np.ndarray]:
    """Feature sets per step of one episode (T, 2) of human actions, each using steps <= t only."""
    n = len(actions)
    padded = np.vstack([np.zeros((WINDOW - 1, 2), np.float32), actions])
    window = np.stack([padded[t:t + WINDOW].ravel() for t in range(n)])
    mean_so_far = np.cumsum(actions, 0) / np.arange(1, n + 1)[:, None]
    min_so_far = np.minimum.accumulate(actions, 0)
    step = np.arange(n, dtype=np.float32)[:, None]
    return {"the current action": actions,
            f"the last {WINDOW} actions": window,
            f"the {WINDOW} actions before this step (what the assistant observes)": previous_actions(actions),
            f"the last {WINDOW} actions + episode mean, min, step": np.hstack([window, mean_so_far, min_so_far, step])}


def load(store: Store, ref: str) -> dict:
    """Per-step feature sets, labels, episode and human groups and the assistant's estimate of
    one artifact's assisted episodes."""
    art = store.get(ref)
    steps = np.load(store.path(art.id, "steps.npz"))
    result = json.loads(store.path(art.id, "eval.json").read_text())
    rows = result["assisted"]
    humans = result["result"]["humans"] if "result" in result else result["panel"]
    sets: dict[str, list[np.ndarray]] = {}
    labels, by_episode, by_human, y_hat = [], [], [], []
    for i, row in enumerate(rows):
        mask = steps["episode"] == i
        if not mask.any():
            continue
        for name, x in features(steps["human_action"][mask]).items():
            sets.setdefault(name, []).append(x)
        n = int(mask.sum())
        labels.append(np.full(n, row["label"]))
        by_episode.append(np.full(n, i))
        by_human.append(np.full(n, row["human"]))
        y_hat.append(steps["y_hat"][mask])
    return {"art": art, "rows": rows, "humans": humans, "x": {k: np.vstack(v) for k, v in sets.items()},
            "y": np.concatenate(labels), "by_episode": np.concatenate(by_episode),
            "by_human": np.concatenate(by_human), "y_hat": np.concatenate(y_hat)}


def across(store_path: str, train_ref: str, test_ref: str) -> None:
    """Fit on every step of one artifact's humans, score on another's (e.g. populations of
    another seed): the held-out bar's ceiling for an estimator reading the human's actions."""
    store = Store(store_path)
    train, test = load(store, train_ref), load(store, test_ref)
    print(f"fit on {train['art'].id[:12]} ({len(train['y'])} steps), scored on {test['art'].id[:12]} "
          f"({len(test['y'])} steps); the assistant's own estimate there: "
          f"{f1_score(test['y'], test['y_hat'], average='macro'):.3f}")
    print("| features of the human's actions | F1 on the other humans |")
    print("|---|---|")
    for name, x in train["x"].items():
        model = HistGradientBoostingClassifier(max_iter=200, random_state=0).fit(x, train["y"])
        print(f"| {name} | {f1_score(test['y'], model.predict(test['x'][name]), average='macro'):.3f} |")


def main(store_path: str, ref: str) -> None:
    data = load(Store(store_path), ref)
    art, rows, humans, y = data["art"], data["rows"], data["humans"], data["y"]
    groups = {"other episodes of the same humans": data["by_episode"], "humans it never saw": data["by_human"]}
    print(f"{art.kind} {art.id[:12]}: {len(rows)} assisted episodes, {len(y)} steps")
    print(f"the assistant's own estimate: per-step F1 {f1_score(y, data['y_hat'], average='macro'):.3f}")
    print("| features of the human's actions | F1, " + " | F1, ".join(groups) + " |")
    print("|---|" + "---|" * len(groups))
    left_out = {}
    for name, x in data["x"].items():
        scores = []
        for group_name, group in groups.items():
            predicted = np.zeros_like(y)
            for train, test in GroupKFold(5).split(x, y, group):
                model = HistGradientBoostingClassifier(max_iter=200, random_state=0).fit(x[train], y[train])
                predicted[test] = model.predict(x[test])
            scores.append(f1_score(y, predicted, average="macro"))
            if group_name == "humans it never saw":
                left_out = {h: float((predicted[group == h] == y[group == h]).mean()) for h in np.unique(group)}
        print(f"| {name} | " + " | ".join(f"{s:.3f}" for s in scores) + " |")
    print("each human left out (richest features): " + ", ".join(
        f"{humans[h]['intent']} {humans[h]['env_step'] / 1000:g}k {acc:.2f}" for h, acc in left_out.items()))


if __name__ == "__main__":
    if len(sys.argv) == 4:
        across(*sys.argv[1:4])
    else:
        main(*sys.argv[1:3])
