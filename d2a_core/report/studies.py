"""The report's section on studies with people (`d2a study`): one table per participant."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from d2a_core.artifacts import Store
from d2a_core.report.render import Block, Cell, Table, short

STUDY_KIND = "study"  # as d2a_core.drive.study, which imports pygame's window lazily only


def collect_studies(store: Store) -> list[dict[str, Any]]:
    """Every stored study (oldest first): participant, assistant, table and its id."""
    out = []
    for art in store.list(STUDY_KIND):
        study = store.read_json(art.id, "study.json")
        out.append({"id": art.id, "participant": study["participant"], "assistant": study["assistant"],
                    "trials": len(study["trials"]), "table": study["table"]})
    return out


def _cells(rows: list[list[str]]) -> list[list[Cell]]:
    return [[Cell([text]) for text in row] for row in rows]


def study_blocks(studies: Sequence[dict[str, Any]]) -> list[Block]:
    blocks = []
    for s in studies:
        blocks.append(Block("h3", f"Participant {s['participant']} ({s['trials']} trials, study {short([s['id']])}, "
                                  f"assistant {short([s['assistant']]) if s['assistant'] else '-'})"))
        rows = [[g["intent"], "assisted" if g["assisted"] else "alone", str(g["trials"]), f"{g['met_intent']:.2f}",
                 f"{g['self_report']:.2f}", f"{g['progress_m']:.0f}", f"{g['collision']:.2f}",
                 f"{g['intervention']:.2f}", "-" if g["read_as_stated"] is None else f"{g['read_as_stated']:.2f}"]
                for g in s["table"]["groups"]]
        blocks.append(Block("table", table=Table(
            ["intent", "drove", "trials", "met intent", "said so", "progress (m)", "collisions", "‖a_A‖",
             "read as stated"], _cells(rows))))
        if s["table"]["paired"]:
            rows = [[p["intent"], str(p["pairs"]), f"{p['progress_change_m']:+.1f}", f"{p['met_intent_change']:+.2f}",
                     f"{p['collision_change']:+.2f}"] for p in s["table"]["paired"]]
            blocks.append(Block("table", table=Table(
                ["intent", "paired starts", "progress change (m)", "met-intent change", "collision change"],
                _cells(rows))))
    return blocks
