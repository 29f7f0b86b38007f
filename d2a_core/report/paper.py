"""The paper's published numbers (`paper_values.yaml`), looked up by track, pair, intent, method."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import yaml

PAPER_VALUES = Path(__file__).with_name("paper_values.yaml")


@functools.lru_cache(maxsize=1)
def load() -> dict[str, Any]:
    """The parsed `paper_values.yaml`."""
    with PAPER_VALUES.open(encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def change_cell(track: str, pair: str, intent: str, method: str, metric: str) -> dict[str, Any] | None:
    """{mean, std, table} of the paper's change over unassisted imperfect humans, or None when
    the paper reports no such cell."""
    values = load()
    metrics = values["metrics"]
    for label, table in values["appendix"].items():
        if table["pair"] != pair:
            continue
        row = table.get(track, {}).get(intent, {}).get(method)
        if row is None or metric not in metrics:
            return None
        mean, std = row[metrics.index(metric)]
        return {"mean": mean, "std": std, "table": label}
    return None


def f1_cell(track: str, pair: str, method: str) -> dict[str, Any] | None:
    """{mean, std, table} of the paper's intent F1 on training humans, or None."""
    f1 = load()["f1"]
    if method != f1["method"] or pair not in f1 or track not in f1[pair]:
        return None
    mean, std = f1[pair][track]
    return {"mean": mean, "std": std, "table": f1["label"]}


def swap_cell(track: str, pair: str, method: str) -> dict[str, Any] | None:
    """The paper's statement on intent recovery after a swap, or None."""
    swap = load()["intent_swap"]
    if (track, pair, method) != (swap["track"], swap["pair"], swap["method"]):
        return None
    return {"recovery_s": swap["recovery_s"], "level": swap["level"], "note": swap["note"], "table": swap["label"]}


def paper_name(method: str) -> str:
    """The paper's name of a method (our name when the paper has none)."""
    return load()["paper_names"].get(method, method)
