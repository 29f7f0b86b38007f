"""Find what the report is made of in the store, by alias, and read it (JSON, JSONL, NPZ only).

What is read, per (track, pair):

- evaluations `eval/<track>/<pair>/<method>/seed<k>` (the humans the assistants trained with) and
  `eval/<track>/<pair>/<method>/seed<k>/humans-<ids>` (held-out populations): `eval.json`;
- intent swaps `intent-swap/<track>/<pair>/<method>/seed<k>`: `swap.json`;
- assistant runs `assistant-runs/<track>/<pair>/<method>/seed<k>`: `run.json`, `curve.jsonl`;
- the human populations the evaluations and runs name (or, without those, `humans/<track>/<intent>`):
  `population.json`, `curve.jsonl`;
- the evaluated assistant checkpoints' manifests, for the preset they were trained with.

Aliases point at the current result of each request, so an evaluation superseded by a rerun is
not counted twice. Every artifact read is registered with `Collected.use`; the report's inputs
are exactly those. Episode files (`steps.npz`, `latents.npz`, MCAP logs) are read by the figures,
which register what they read the same way.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.report.presets import describe

METHOD_ORDER = ("dreamer", "dreamer-ail", "dream2assist", "dream2assist+a", "dream2assist+a-r", "no-rssm")
"""The paper's row order; other methods follow by name."""

_PART = r"[A-Za-z0-9][A-Za-z0-9_.+-]*"
EVAL_ALIAS = re.compile(rf"^eval/(?P<track>{_PART})/(?P<pair>{_PART})/(?P<method>{_PART})/seed(?P<seed>\d+)"
                        rf"(?P<heldout>/humans-{_PART})?$")
SWAP_ALIAS = re.compile(rf"^intent-swap/(?P<track>{_PART})/(?P<pair>{_PART})/(?P<method>{_PART})/seed(?P<seed>\d+)$")
RUN_ALIAS = re.compile(rf"^assistant-runs/(?P<track>{_PART})/(?P<pair>{_PART})/(?P<method>{_PART})/seed(?P<seed>\d+)$")
POPULATION_ALIAS = re.compile(rf"^humans/(?P<track>{_PART})/(?P<intent>{_PART})$")

PRODUCERS = (
    "d2a train-humans --track T --intent I   (populations: human learning curves)",
    "d2a train-assistant --track T --pair P --method M --seed K   (assistant learning curves)",
    "d2a eval --track T --pair P --baseline M   (Table 1, the appendix tables, F1, per-human bars, "
    "time traces, t-SNE)",
    "d2a intent-swap --track T --pair P --baseline M   (intent-swap recovery)",
)


def method_key(method: str) -> tuple[int, str]:
    """Sort key: the paper's row order, then by name."""
    return (METHOD_ORDER.index(method) if method in METHOD_ORDER else len(METHOD_ORDER), method)


@dataclass
class Evaluation:
    id: str
    alias: str
    track: str
    pair: str
    method: str
    seed: int
    heldout: bool
    result: dict[str, Any]
    assisted: list[dict[str, Any]]
    files: frozenset[str]
    assistant: str
    preset: str


@dataclass
class Swap:
    id: str
    alias: str
    track: str
    pair: str
    method: str
    seed: int
    result: dict[str, Any]
    preset: str


@dataclass
class Run:
    id: str
    alias: str
    track: str
    pair: str
    method: str
    seed: int
    run: dict[str, Any]
    curve: list[dict[str, Any]]
    preset: str


@dataclass
class Population:
    id: str
    track: str
    intent: str
    seed: int | None
    population: dict[str, Any]
    curve: list[dict[str, Any]]
    preset: str


@dataclass
class Collected:
    store: Store
    evaluations: list[Evaluation] = field(default_factory=list)
    swaps: list[Swap] = field(default_factory=list)
    runs: list[Run] = field(default_factory=list)
    populations: list[Population] = field(default_factory=list)
    used: set[str] = field(default_factory=set)

    def use(self, art_id: str) -> str:
        self.used.add(art_id)
        return art_id

    def pairs(self) -> list[tuple[str, str]]:
        """(track, pair) of everything collected, sorted."""
        found = {(e.track, e.pair) for e in self.evaluations} | {(s.track, s.pair) for s in self.swaps} | \
                {(r.track, r.pair) for r in self.runs}
        return sorted(found)

    def empty(self) -> bool:
        return not (self.evaluations or self.swaps or self.runs or self.populations)


def read_jsonl(store: Store, art_id: str, name: str) -> list[dict[str, Any]]:
    text = store.read_bytes(art_id, name).decode("utf-8")
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _wanted(value: str, allowed: Sequence[str] | None) -> bool:
    return not allowed or value in allowed


def collect(store: Store, tracks: Sequence[str] | None = None, pairs: Sequence[str] | None = None) -> Collected:
    """Everything reportable for the tracks and pairs asked for (all when None)."""
    out = Collected(store)
    refs = store.refs()
    kinds: dict[str, str] = {}

    def kind_of(art_id: str) -> str:
        if art_id not in kinds:
            kinds[art_id] = store.get(art_id).kind
        return kinds[art_id]

    presets: dict[str, str] = {}

    def preset_of(art_id: str, pair: str | None = None) -> str:
        if art_id not in presets:
            presets[art_id] = describe(store.get(art_id).config, pair)
        return presets[art_id]

    seen_tracks: set[str] = set()
    seen_pairs: set[str] = set()
    for alias, art_id in refs.items():
        for pattern in (EVAL_ALIAS, SWAP_ALIAS, RUN_ALIAS):
            m = pattern.match(alias)
            if m:
                seen_tracks.add(m["track"])
                seen_pairs.add(m["pair"])
                break
        else:
            continue
        if not (_wanted(m["track"], tracks) and _wanted(m["pair"], pairs)):
            continue
        key = dict(track=m["track"], pair=m["pair"], method=m["method"], seed=int(m["seed"]))
        if pattern is EVAL_ALIAS and kind_of(art_id) == "evaluation":
            stored = store.read_json(art_id, "eval.json")
            result = stored["result"]
            assistant = result["assistant"]
            out.evaluations.append(Evaluation(
                out.use(art_id), alias, **key, heldout=m["heldout"] is not None, result=result,
                assisted=stored.get("assisted", []), files=frozenset(store.get(art_id).files),
                assistant=out.use(assistant), preset=preset_of(assistant, key["pair"])))
        elif pattern is SWAP_ALIAS and kind_of(art_id) == "intent-swap":
            result = store.read_json(art_id, "swap.json")["result"]
            out.use(result["assistant"])
            out.swaps.append(Swap(out.use(art_id), alias, **key, result=result, preset=preset_of(result["assistant"], key["pair"])))
        elif pattern is RUN_ALIAS and kind_of(art_id) == "assistant-run":
            out.runs.append(Run(out.use(art_id), alias, **key, run=store.read_json(art_id, "run.json"),
                                curve=read_jsonl(store, art_id, "curve.jsonl"), preset=preset_of(art_id, key["pair"])))

    for name, asked, seen in (("track", tracks, seen_tracks), ("pair", pairs, seen_pairs)):
        unknown = sorted(set(asked or ()) - seen)
        if unknown and seen:
            raise UsageError(f"no evaluation, intent swap or assistant run for {name} {', '.join(unknown)} in store "
                             f"{store.root}; it has: {', '.join(sorted(seen))}")

    # the populations behind what was collected; without any, the aliased ones of the tracks asked for
    population_ids = {p for e in out.evaluations for p in e.result.get("populations", [])} | \
                     {p for r in out.runs for p in r.run.get("populations", [])}
    if not population_ids and not out.evaluations and not out.runs:
        intents = {i for p in pairs or () for i in p.split("-")}
        for alias, art_id in refs.items():
            m = POPULATION_ALIAS.match(alias)
            if m and _wanted(m["track"], tracks) and (not intents or m["intent"] in intents):
                population_ids.add(art_id)
    for art_id in sorted(population_ids):
        art = store.get(art_id)
        if art.kind != "population":
            continue
        pop = store.read_json(art_id, "population.json")
        out.populations.append(Population(out.use(art_id), pop["track"], pop["intent"], pop.get("seed"), pop,
                                          read_jsonl(store, art_id, "curve.jsonl"), preset_of(art_id)))

    def order(x: Any) -> tuple:
        return (x.track, x.pair, method_key(x.method), x.seed, getattr(x, "heldout", False), x.alias)

    out.evaluations.sort(key=order)
    out.swaps.sort(key=order)
    out.runs.sort(key=order)
    out.populations.sort(key=lambda p: (p.track, p.intent, p.seed if p.seed is not None else -1, p.id))
    return out


def nothing_to_report(store: Store, tracks: Sequence[str] | None, pairs: Sequence[str] | None) -> UsageError:
    """The error for a store (or a selection) with nothing to report: which commands make the inputs."""
    where = ""
    if tracks or pairs:
        where = " for " + " ".join([*(f"--track {t}" for t in tracks or ()), *(f"--pair {p}" for p in pairs or ())])
    lines = "\n  ".join(PRODUCERS)
    return UsageError(f"nothing to report in store {store.root}{where}: no evaluation, intent-swap, assistant-run "
                      f"or population artifacts. Make them with:\n  {lines}")
