"""`d2a report`: the paper's tables and figures from the store, as a `report` artifact.

The report reads only artifacts (JSON, JSONL, NPZ and MCAP files; never torch or the simulator):
evaluations, intent swaps, assistant runs, populations and the evaluated assistants' manifests
(`collect`). It writes one artifact of kind `report` with `report.md`, `report.html` (self-contained),
`tables.json` and `figures/<name>.png|svg`, whose inputs are exactly the artifacts it read, and
tags it `report/latest`. Nothing in it depends on the time, the store's path or the machine, so
the same store content gives the same bytes and the same report id.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.report import render
from d2a_core.report.collect import Collected, collect, nothing_to_report
from d2a_core.report.figures import make_figures
from d2a_core.report.studies import collect_studies
from d2a_core.report.stats import BOOTSTRAP_METHOD, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, CONFIDENCE, MIN_SEEDS
from d2a_core.report.tables import build_tables

REPORT_FORMAT = 1
LATEST = "report/latest"


def _summary(data: Collected, tracks: Sequence[str] | None, pairs: Sequence[str] | None) -> str:
    evaluations = Counter(e.method for e in data.evaluations if not e.heldout)
    held = sum(e.heldout for e in data.evaluations)
    parts = [f"{n} {m}" for m, n in sorted(evaluations.items())]
    selection = " ".join([*(f"--track {t}" for t in tracks or ()), *(f"--pair {p}" for p in pairs or ())])
    text = (f"Made with `d2a report{' ' + selection if selection else ''}` from the store's aliased artifacts: "
            f"{len(data.evaluations) - held} evaluations on the training humans ({', '.join(parts) or 'none'}), "
            f"{held} on held-out humans, {len(data.swaps)} intent swaps, {len(data.runs)} assistant runs, "
            f"{len(data.populations)} human populations. Settings: "
            + (", ".join(f"{t} {p}" for t, p in data.pairs()) or "none") + ".")
    return text


def _artifact_rows(store: Store, ids: Sequence[str]) -> list[dict[str, Any]]:
    refs = store.refs()
    return [{"id": i, "kind": store.get(i).kind, "aliases": sorted(a for a, t in refs.items() if t == i)} for i in ids]


def build_report(store: Store, tracks: Sequence[str] | None = None, pairs: Sequence[str] | None = None,
                 out: str | Path | None = None) -> dict[str, Any]:
    """Build (or find, when unchanged) the report of `tracks` and `pairs` (all when empty)."""
    tracks = sorted(set(tracks)) if tracks else None
    pairs = sorted(set(pairs)) if pairs else None
    if out is not None and Path(out).exists() and not Path(out).is_dir():  # before minutes of building
        raise UsageError(f"--out {out} exists and is not a directory; give a directory")
    if store.count() == 0:  # before the lease, which would create a store where there is none
        raise nothing_to_report(store, tracks, pairs)
    with store.lease():
        data = collect(store, tracks, pairs)
        studies = collect_studies(store)
        if data.empty() and not studies:
            raise nothing_to_report(store, tracks, pairs)
        tables = build_tables(data, tracks, pairs)
        tables["studies"] = studies
        data.used.update(study["id"] for study in tables["studies"])
        figures = make_figures(data)
        inputs = sorted(data.used)
        doc = {"summary": _summary(data, tracks, pairs), "tables": tables, "skipped": figures.skipped,
               "artifacts": _artifact_rows(store, inputs)}
        blocks = render.document(doc, figures.plots)
        files = {"report.md": render.markdown(blocks).encode("utf-8"),
                 "report.html": render.to_html(blocks).encode("utf-8")}
        for plot in figures.plots:
            files[f"figures/{plot.name}.png"] = plot.png
            files[f"figures/{plot.name}.svg"] = plot.svg
        figure_index = [{"name": p.name, "kind": p.kind, "title": p.title, "caption": p.caption,
                         "sources": p.sources, "files": [f"figures/{p.name}.png", f"figures/{p.name}.svg"]}
                        for p in figures.plots]
        settings = {"format": REPORT_FORMAT, "tracks": tracks, "pairs": pairs,
                    "bootstrap": {"confidence": CONFIDENCE, "resamples": BOOTSTRAP_RESAMPLES, "seed": BOOTSTRAP_SEED,
                                  "method": BOOTSTRAP_METHOD, "min_seeds": MIN_SEEDS}}
        tables_json = {"format": REPORT_FORMAT, "settings": settings, "tables": tables, "figures": figure_index,
                       "skipped_figures": figures.skipped, "inputs": inputs}
        files["tables.json"] = (json.dumps(tables_json, indent=1, sort_keys=True, ensure_ascii=False,
                                           allow_nan=False) + "\n").encode("utf-8")
        labels = {"tracks": ",".join(tracks) if tracks else "all", "pairs": ",".join(pairs) if pairs else "all"}
        with store.create("report", inputs=inputs, config=settings, seed=BOOTSTRAP_SEED, labels=labels) as writer:
            for name in sorted(files):
                writer.add_bytes(name, files[name])
        art_id = writer.artifact.id
        store.tag(art_id, LATEST)
        exported = [str(p) for p in store.export(art_id, out)] if out is not None else []
    return {"id": art_id, "files": sorted(files), "tables": tables, "figures": figure_index,
            "skipped_figures": figures.skipped, "inputs": inputs, "alias": LATEST,
            "out": str(out) if out is not None else None, "exported": exported}
