"""One setting's `d2a eval` results across population builds and assistant seeds, against the
pass-stay bars of the safety work: every run's intent F1 >= 0.90 and their mean >= 0.95; the
weak (imperfect) drivers of each intent gain progress and their intent's criterion on the mean
over runs; no group's collision rate, nor its off-track rate, up by more than 0.05 on the mean
over runs (the safety rule, `d2a_core.evaluation.safety`). The off-track rate is read from the
episode rows, so evaluations stored before `d2a eval` recorded it are covered too.

    python docs/analysis/spread.py SETTING=STORE:EVAL_ID [SETTING=STORE:EVAL_ID ...]

SETTING names the setting (e.g. `quick`, `exact`); runs with the same name are averaged. STORE is
an artifact store, EVAL_ID an `evaluation` artifact id (or alias) in it. Prints one markdown row
per run, then one row per setting with the mean over its runs and the bars it misses.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from statistics import mean

from d2a_core.artifacts import Store
from d2a_core.evaluation.safety import breaks_rule
from d2a_core.pipelines.evaluate import CRITERION
from eval_table import GROUPS  # this script's folder is on the path when it runs
F1_EACH, F1_MEAN = 0.90, 0.95


def off_track_change(stored: dict, intent: str, group: str) -> float:
    """The group's mean per-human change in the share of episodes that ended off the track."""
    humans = [k for k, h in enumerate(stored["result"]["humans"]) if h["intent"] == intent and h["group"] == group]
    share = {kind: {k: mean(r["off_track"] for r in stored[kind] if r["human"] == k) for k in humans}
             for kind in ("unassisted", "assisted")}
    return mean(share["assisted"][k] - share["unassisted"][k] for k in humans)


def figures(stored: dict) -> dict:
    """Per intent and group: progress change, criterion before / after, collision and off-track
    changes, ||a_A||."""
    result = stored["result"]
    out = {"f1": result["intent_f1"]}
    for intent, blocks in result["intents"].items():
        for group in GROUPS:
            if group not in blocks:
                continue
            b = blocks[group]
            before = b[f"{CRITERION}_unassisted"]["mean"]
            out[(intent, group)] = {"progress": b["progress_m"]["mean"], "before": before,
                                    "after": before + b[CRITERION]["mean"],
                                    "collision": b["collision"]["mean"],
                                    "off_track": off_track_change(stored, intent, group),
                                    "intervention": b["intervention"]["mean"]}
    return out


def f1_text(values: list[float | None]) -> str:
    known = [v for v in values if v is not None]
    return f"{mean(known):.3f}" if known else "-"


def cell(g: dict) -> str:
    return (f"{g['progress']:+.0f} m, {g['before']:.2f} → {g['after']:.2f}, {g['collision']:+.2f}, "
            f"{g['off_track']:+.2f}, {g['intervention']:.2f}")


def misses(runs: list[dict], keys: list[tuple[str, str]]) -> list[str]:
    out = []
    f1s = [r["f1"] for r in runs if r["f1"] is not None]  # methods without an intent estimate have none
    low = [f1 for f1 in f1s if f1 < F1_EACH]
    if low:
        out.append(f"F1 below {F1_EACH} on {len(low)} run(s)")
    if f1s and mean(f1s) < F1_MEAN:
        out.append(f"mean F1 below {F1_MEAN}")
    for intent, group in keys:
        gs = [r[(intent, group)] for r in runs]
        if group == "imperfect":
            if mean(g["progress"] for g in gs) <= 0:
                out.append(f"{intent} weak: no progress gain")
            if mean(g["after"] - g["before"] for g in gs) <= 0:
                out.append(f"{intent} weak: criterion not gained")
        for metric, name in (("collision", "collisions"), ("off_track", "off track")):
            change = mean(g[metric] for g in gs)
            if breaks_rule(change):
                out.append(f"{intent} {group.replace('_', '-')}: {name} {change:+.2f}")
    return out


def main(specs: list[str]) -> None:
    by_setting: dict[str, list[dict]] = defaultdict(list)
    rows = []
    keys: list[tuple[str, str]] = []
    for spec in specs:
        setting, _, where = spec.partition("=")
        store_path, _, ref = where.rpartition(":")
        store = Store(store_path)
        stored = store.read_json(store.resolve(ref), "eval.json")
        result = stored["result"]
        f = figures(stored)
        keys = keys or [k for k in f if k != "f1"]
        by_setting[setting].append(f)
        rows.append((setting, f"seed {result['seed']} `{result['assistant'][:12]}` ({store_path})", f))
    print("| setting | run | F1 | " + " | ".join(f"{i} {g.replace('_', '-')}" for i, g in keys) + " |")
    print("|---|---|---|" + "---|" * len(keys))
    for setting, name, f in rows:
        print(f"| {setting} | {name} | {f1_text([f['f1']])} | " + " | ".join(cell(f[k]) for k in keys) + " |")
    print()
    print("| setting | runs | mean F1 | " + " | ".join(f"{i} {g.replace('_', '-')}" for i, g in keys)
          + " | bars missed |")
    print("|---|---|---|" + "---|" * len(keys) + "---|")
    for setting, runs in by_setting.items():
        means = {k: {m: mean(r[k][m] for r in runs) for m in runs[0][k]} for k in keys}
        missed = misses(runs, keys)
        print(f"| {setting} | {len(runs)} | {f1_text([r['f1'] for r in runs])} | "
              + " | ".join(cell(means[k]) for k in keys) + f" | {'; '.join(missed) or 'none'} |")
    print("\nEach group: progress change, the intent's criterion unassisted → assisted (pass: finished "
          "ahead; stay: finished never ahead), collision-rate change, off-track-rate change, intervention ||a_A||; means over "
          "the group's humans, and in the second table over the setting's runs.")


if __name__ == "__main__":
    main(sys.argv[1:])
