"""The report's tables as data (what `tables.json` and `d2a report --json` hold); `render` prints them.

- `change_tables`: Table 1 and the appendix tables (tab:pass_stay, tab:left_right): per track,
  pair, intent and group of humans, each method's change over the same humans unassisted in
  progress, return, collisions, interventions and speed, and (not in the paper) in the humans' own
  intent criterion (`evaluation.criteria`: pass finished ahead, stay finished never ahead,
  left/right the side held), which progress alone cannot see: an assistant can raise a pass
  driver's progress by keeping it behind the opponent. Per cell: mean +- std over every
  (training seed, human) value, as the paper aggregates; the 95 % bootstrap CI of the mean over
  training seeds (one value per seed: its mean over humans); the interquartile mean of the
  (seed, human) values; the paper's value; the evaluation artifacts it came from.
- `f1_tables`: per-step intent F1 (macro over the pair's intents), on the training humans and on
  held-out populations, per method: mean +- std over seeds, CI; the paper's tab:f1-scores.
- `swap_tables`: per direction of an intent swap, the time until the mean intent accuracy is back
  at its recovery level, the per-trial median, and the paired change in the swap trials' metrics.

Marks, as the paper's tables: `improved` (the paper's blue) when the change, rounded as printed,
is better than none in the metric's direction; `best` (bold) for the best printed mean among two
or more methods. The paper's own values are marked by the same rule among the paper's rows.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from d2a_core.evaluation.criteria import CRITERION_KEY
from d2a_core.evaluation.safety import SAFETY_METRICS, breaks_rule
from d2a_core.report import paper
from d2a_core.report.collect import Collected, Evaluation, method_key
from d2a_core.report.stats import MIN_SEEDS, bootstrap_ci, ci_text, iqm, mean_std

INTENT_MET = CRITERION_KEY
"""`d2a eval`'s per-human intent criterion; evaluations made before it was recorded have no value,
and their cells say so."""
METRICS = ("progress_m", "return", "collision", "off_track", "intervention", "mean_speed_m_s", INTENT_MET)
HIGHER_IS_BETTER = {"progress_m": True, "return": True, "collision": False, "off_track": False, "intervention": False,
                    "mean_speed_m_s": True, INTENT_MET: True}
DECIMALS = {"progress_m": 1, "return": 1, "collision": 2, "off_track": 2, "intervention": 2, "mean_speed_m_s": 1, INTENT_MET: 2}
HEADERS = {"progress_m": "Progress (m)", "return": "Return", "collision": "Collisions", "off_track": "Off track",
           "intervention": "Interventions", "mean_speed_m_s": "Speed (m/s)", INTENT_MET: "Intent met"}
MARKED = ("progress_m", "return", "collision", "off_track", "mean_speed_m_s", INTENT_MET)
"""Metrics marked (blue, bold) as the paper marks its own; interventions it leaves unmarked."""
GROUPS = ("imperfect", "near_perfect")
SWAP_METRICS = ("progress_m", "collision", "intervention", "mean_speed_m_s")


def _r(value: float | None, digits: int = 6) -> float | None:
    return None if value is None else round(float(value), digits)


def improved(mean: float | None, metric: str) -> bool:
    """Better than no change in the metric's direction, as printed (the paper's blue; never for
    interventions, which are zero unassisted)."""
    if mean is None or metric not in MARKED:
        return False
    shown = round(mean, DECIMALS[metric])
    return shown > 0 if HIGHER_IS_BETTER[metric] else shown < 0


def mark_best(cells: Sequence[dict[str, Any] | None], metric: str) -> None:
    """Set `best` on the cells whose printed mean is the best of two or more (the paper's bold;
    like the paper, not for interventions, a cost rather than an outcome)."""
    shown = [(c, round(c["mean"], DECIMALS[metric])) for c in cells if c is not None and c.get("mean") is not None]
    for cell, _ in shown:
        cell["best"] = False
    if len(shown) < 2 or metric not in MARKED:
        return
    best = max(v for _, v in shown) if HIGHER_IS_BETTER[metric] else min(v for _, v in shown)
    for cell, value in shown:
        cell["best"] = value == best


def seed_cell(per_seed: dict[int, Sequence[float]], metric_decimals: int, sources: Iterable[str]) -> dict[str, Any]:
    """Statistics of one cell from {seed: values of that seed}: mean +- std and IQM over all values,
    the bootstrap CI over the per-seed means."""
    pooled = [v for seed in sorted(per_seed) for v in per_seed[seed]]
    seed_means = [float(np.mean(per_seed[s])) for s in sorted(per_seed) if len(per_seed[s])]
    mean, std = mean_std(pooled)
    ci = bootstrap_ci(seed_means)
    return {"mean": _r(mean), "std": _r(std), "iqm": _r(iqm(pooled)), "n_values": len(pooled),
            "n_seeds": len(seed_means), "seeds": sorted(per_seed), "seed_means": [_r(v) for v in seed_means],
            "ci": None if ci is None else [_r(ci[0]), _r(ci[1])],
            "ci_text": ci_text(ci, len(seed_means), metric_decimals), "sources": sorted(set(sources))}


def _humans_preset(data: Collected, evaluations: Sequence[Evaluation]) -> list[str]:
    by_id = {p.id: p for p in data.populations}
    return sorted({by_id[p].preset for e in evaluations for p in e.result.get("populations", []) if p in by_id})


def _evaluations(data: Collected, track: str, pair: str, heldout: bool = False) -> list[Evaluation]:
    return [e for e in data.evaluations if (e.track, e.pair, e.heldout) == (track, pair, heldout)]


def change_tables(data: Collected) -> list[dict[str, Any]]:
    tables = []
    for track, pair in data.pairs():
        evaluations = _evaluations(data, track, pair)
        if not evaluations:
            continue
        for intent in pair.split("-"):
            for group in GROUPS:
                table = _change_table(data, track, pair, intent, group, evaluations)
                if table is not None:
                    tables.append(table)
    return tables


def _change_table(data: Collected, track: str, pair: str, intent: str, group: str,
                  evaluations: Sequence[Evaluation]) -> dict[str, Any] | None:
    by_method: dict[str, list[Evaluation]] = defaultdict(list)
    for e in evaluations:
        by_method[e.method].append(e)
    paper_methods = [m for m in paper.load()["paper_names"]
                     if group == "imperfect" and paper.change_cell(track, pair, intent, m, METRICS[0])]
    methods = sorted(set(by_method) | set(paper_methods), key=method_key)
    rows = []
    used_evaluations: list[Evaluation] = []
    humans_per_seed: set[int] = set()
    for method in methods:
        per_metric: dict[str, dict[int, list[float]]] = {m: defaultdict(list) for m in METRICS}
        sources = []
        for e in by_method.get(method, []):
            humans = [h for h in e.result.get("humans", []) if h["intent"] == intent and h["group"] == group]
            if not humans:
                continue
            sources.append(e.id)
            used_evaluations.append(e)
            humans_per_seed.add(len(humans))
            for m in METRICS:
                per_metric[m][e.seed].extend(h["delta"][m] for h in humans if h["delta"].get(m) is not None)
        ran = bool(sources)
        if not ran and method not in paper_methods:
            continue
        cells = {}
        for m in METRICS:
            cell = seed_cell(per_metric[m], DECIMALS[m], sources) if ran else {"mean": None, "sources": []}
            cell["improved"] = improved(cell["mean"], m)
            ref = paper.change_cell(track, pair, intent, method, m) if group == "imperfect" else None
            if ref is not None:
                ref["improved"] = improved(ref["mean"], m)
            cell["paper"] = ref
            cells[m] = cell
        # the safety rule (`evaluation.safety`), on the mean over every (training seed, human) value
        for m in SAFETY_METRICS:
            cells[m]["unsafe"] = ran and breaks_rule(cells[m]["mean"])
        rows.append({"method": method, "name": paper.paper_name(method), "ran": ran,
                     "seeds": sorted({e.seed for e in by_method.get(method, []) if e.id in sources}),
                     "cells": cells, "sources": sources})
    if not any(r["ran"] for r in rows):
        return None
    for m in METRICS:
        mark_best([r["cells"][m] if r["ran"] else None for r in rows], m)
        mark_best([r["cells"][m]["paper"] for r in rows], m)
    return {
        "id": f"change/{track}/{pair}/{intent}/{group}", "track": track, "pair": pair, "intent": intent,
        "group": group, "metrics": list(METRICS),
        "paper_table": next((c["paper"]["table"] for r in rows for c in r["cells"].values() if c["paper"]), None),
        "seeds": {r["method"]: r["seeds"] for r in rows if r["ran"]},
        "humans_per_seed": sorted(humans_per_seed),
        "episodes_per_human": sorted({e.result.get("episodes_per_human") for e in used_evaluations} - {None}),
        "preset": {"assistants": sorted({e.preset for e in used_evaluations}),
                   "humans": _humans_preset(data, used_evaluations)},
        "rows": rows, "sources": sorted({e.id for e in used_evaluations}),
        "unsafe": [r["method"] for r in rows if r["ran"] and any(r["cells"][m]["unsafe"] for m in SAFETY_METRICS)],
    }


def _f1_block(evaluations: Sequence[Evaluation], intents: Sequence[str]) -> dict[str, Any] | None:
    scored = [e for e in evaluations if e.result.get("intent_f1") is not None]
    if not scored:
        return None
    cell = seed_cell({e.seed: [e.result["intent_f1"]] for e in scored}, 3, [e.id for e in scored])
    per_intent = {}
    for intent in intents:
        values = [e.result.get("intents", {}).get(intent, {}).get("intent_f1") for e in scored]
        per_intent[intent] = _r(mean_std(values)[0])
    cell["per_intent"] = per_intent
    cell["episodes_per_human"] = sorted({e.result.get("episodes_per_human") for e in scored} - {None})
    cell["populations"] = sorted({p for e in scored for p in e.result.get("populations", [])})
    return cell


def f1_tables(data: Collected) -> list[dict[str, Any]]:
    tables = []
    for track, pair in data.pairs():
        train = _evaluations(data, track, pair)
        held = _evaluations(data, track, pair, heldout=True)
        if not train and not held:
            continue
        intents = pair.split("-")
        methods = sorted({e.method for e in [*train, *held]} | ({paper.load()["f1"]["method"]}
                         if paper.f1_cell(track, pair, paper.load()["f1"]["method"]) else set()), key=method_key)
        rows, no_estimate = [], []
        for method in methods:
            t = _f1_block([e for e in train if e.method == method], intents)
            h = _f1_block([e for e in held if e.method == method], intents)
            ref = paper.f1_cell(track, pair, method)
            ran = any(e.method == method for e in [*train, *held])
            if t is None and h is None and ran:
                no_estimate.append(method)
                continue
            rows.append({"method": method, "name": paper.paper_name(method), "ran": ran, "training": t,
                         "heldout": h, "paper": ref,
                         "sources": sorted({*(t or {}).get("sources", []), *(h or {}).get("sources", [])})})
        if not any(r["ran"] for r in rows) and not no_estimate:
            continue
        tables.append({"id": f"f1/{track}/{pair}", "track": track, "pair": pair, "rows": rows,
                       "no_intent_estimate": no_estimate, "paper_table": paper.load()["f1"]["label"],
                       "preset": sorted({e.preset for e in [*train, *held]}),
                       "episodes_per_human": sorted({e.result.get("episodes_per_human") for e in [*train, *held]}
                                                    - {None}),
                       "sources": sorted({s for r in rows for s in r["sources"]})})
    return tables


def swap_tables(data: Collected) -> list[dict[str, Any]]:
    tables = []
    for track, pair in data.pairs():
        swaps = [s for s in data.swaps if (s.track, s.pair) == (track, pair)]
        if not swaps:
            continue
        intents = pair.split("-")
        directions = [f"{intents[0]}-to-{intents[1]}", f"{intents[1]}-to-{intents[0]}"]
        rows = []
        for method in sorted({s.method for s in swaps}, key=method_key):
            mine = [s for s in swaps if s.method == method]
            row: dict[str, Any] = {"method": method, "name": paper.paper_name(method),
                                   "seeds": sorted(s.seed for s in mine), "directions": {},
                                   "paper": paper.swap_cell(track, pair, method), "sources": [s.id for s in mine]}
            for d in directions:
                curves = [(s, s.result.get("directions", {}).get(d)) for s in mine]
                curves = [(s, c) for s, c in curves if c]
                if not curves:
                    row["directions"][d] = None
                    continue
                reached = {s.seed: [c["recovery_s"]] for s, c in curves if c.get("recovery_s") is not None}
                cell = seed_cell(reached, 1, [s.id for s, _ in curves])
                cell["seeds_recovered"] = len(reached)
                cell["seeds_total"] = len(curves)
                medians = [c.get("median_trial_recovery_s") for _, c in curves]
                cell["median_trial_recovery_s"] = _r(mean_std(medians)[0])
                cell["recovered_trials"] = sum(c.get("recovered_trials", 0) for _, c in curves)
                cell["trials"] = sum(c.get("trials", 0) for _, c in curves)
                metrics = {}
                for m in SWAP_METRICS:
                    values = [s.result.get("metrics", {}).get(d, {}).get(m, {}).get("delta_mean") for s, _ in curves]
                    mean, std = mean_std(values)
                    metrics[m] = {"mean": _r(mean), "std": _r(std), "improved": improved(mean, m)}
                cell["metrics"] = metrics
                row["directions"][d] = cell
            rows.append(row)
        first = swaps[0].result
        tables.append({"id": f"swap/{track}/{pair}", "track": track, "pair": pair, "directions": directions,
                       "rows": rows,
                       "trials_per_direction": sorted({s.result.get("trials_per_direction") for s in swaps} - {None}),
                       "recovery_level": first.get("recovery_level"), "hold_s": first.get("hold_s"),
                       "preset": sorted({s.preset for s in swaps}),
                       "window_s": first.get("window_s"), "sources": sorted(s.id for s in swaps)})
    return tables


def not_run(data: Collected, tracks: Sequence[str] | None, pairs: Sequence[str] | None) -> list[dict[str, str]]:
    """The paper's (track, pair) settings with no evaluation here, and the command that makes one."""
    have = {(e.track, e.pair) for e in data.evaluations if not e.heldout}
    out = []
    for label, table in paper.load()["appendix"].items():
        pair = table["pair"]
        for track in ("hairpin", "straightaway"):
            if (track, pair) in have or (tracks and track not in tracks) or (pairs and pair not in pairs):
                continue
            out.append({"track": track, "pair": pair, "paper_table": label,
                        "command": f"d2a train-assistant --track {track} --pair {pair} --method dream2assist "
                                   f"--method dreamer && d2a eval --track {track} --pair {pair} --baseline dreamer"})
    return out


def build_tables(data: Collected, tracks: Sequence[str] | None = None,
                 pairs: Sequence[str] | None = None) -> dict[str, Any]:
    return {"change": change_tables(data), "f1": f1_tables(data), "intent_swap": swap_tables(data),
            "not_run": not_run(data, tracks, pairs), "min_seeds_for_ci": MIN_SEEDS}
