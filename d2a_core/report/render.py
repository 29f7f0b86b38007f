"""The report as a document: blocks (headings, paragraphs, tables, figures) built once from the
tables' data, written as Markdown (`report.md`) and as one self-contained HTML page
(`report.html`, figures inline as PNG).

Marks as the paper's tables: ▲ (HTML: blue cell) a change better than none in the metric's
direction (the paper's blue), **bold** the best of the methods (the paper's bold). Every table row
names the artifacts its cells come from (HTML: also on each cell, as a tooltip); every figure
names its artifacts under its caption.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from d2a_core.evaluation.safety import SAFETY_MARGIN
from d2a_core.report.figures import Plot
from d2a_core.report.stats import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, CONFIDENCE, MIN_SEEDS
from d2a_core.report.tables import DECIMALS, HEADERS, HIGHER_IS_BETTER, SWAP_METRICS

UP, DOWN, IMPROVED = "↑", "↓", "▲"
UNSAFE = "⚠ unsafe"  # a collision or off-track change that breaks the safety rule (`evaluation.safety`)
SHORT = 12


@dataclass
class Cell:
    lines: list[str]
    bold: bool = False
    improved: bool = False
    title: str = ""


@dataclass
class Table:
    header: list[str]
    rows: list[list[Cell]]


@dataclass
class Block:
    kind: str  # h1 h2 h3 p table figure
    text: str = ""
    table: Table | None = None
    plot: Plot | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def short(ids: Sequence[str]) -> str:
    return ", ".join(f"`{i[:SHORT]}`" for i in ids) if ids else "-"


def _num(value: float, decimals: int, signed: bool = True) -> str:
    return f"{value:+.{decimals}f}" if signed else f"{value:.{decimals}f}"


def _paper_num(value: float) -> str:
    """A typed paper value as printed there (up to 3 decimals, at least one)."""
    text = f"{value:.3f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def _sources_title(ids: Sequence[str]) -> str:
    return "from: " + ", ".join(ids) if ids else ""


INTENT_MET_TEXT = {"pass": "the share of episodes finished ahead of the opponent",
                   "stay": "the share of episodes finished without ever getting ahead",
                   "left": "the share of steps held left of the opponent while racing it",
                   "right": "the share of steps held right of the opponent while racing it"}
"""What the Intent met column counts, per intent (`evaluation.criteria.CRITERION_METRIC`)."""


def _ours_change(cell: dict[str, Any], metric: str, ran: bool) -> Cell:
    if cell.get("mean") is None:
        # a method that ran but has no value here: evaluations older than the metric
        return Cell(["not recorded" if ran else "not run"])
    d = DECIMALS[metric]
    lines = [f"{_num(cell['mean'], d)} ± {cell['std']:.{d}f}" + (f" {IMPROVED}" if cell["improved"] else "")
             + (f" {UNSAFE}" if cell.get("unsafe") else ""),
             f"CI {cell['ci_text']} · IQM {_num(cell['iqm'], d)}"]
    return Cell(lines, bold=cell.get("best", False), improved=cell["improved"], title=_sources_title(cell["sources"]))


def _paper_change(ref: dict[str, Any] | None) -> Cell:
    if ref is None:
        return Cell(["not in the paper"])
    text = f"{_paper_num(ref['mean'])} ± {_paper_num(ref['std'])}" + (f" {IMPROVED}" if ref["improved"] else "")
    return Cell([text], bold=ref.get("best", False), improved=ref["improved"], title=ref["table"])


def _seeds_text(seeds: dict[str, list[int]], names: dict[str, str]) -> str:
    return "; ".join(f"{names.get(m, m)} {', '.join(map(str, s))} ({len(s)})" for m, s in seeds.items())


def change_blocks(tables: Sequence[dict[str, Any]]) -> list[Block]:
    blocks = []
    for t in tables:
        group = "imperfect humans 1-5" if t["group"] == "imperfect" else "near-perfect humans"
        blocks.append(Block("h3", f"{t['track']}, {t['pair']}: {t['intent']} humans, {group}"))
        names = {r["method"]: r["name"] for r in t["rows"]}
        episodes = ", ".join(map(str, t["episodes_per_human"])) or "?"
        per_seed = ", ".join(map(str, t["humans_per_seed"])) or "?"
        paper_note = (f"Paper: `{t['paper_table']}` (its Table 1 `tab:ablations` repeats progress, return and "
                      "collisions), four seeds." if t["paper_table"] else
                      "Paper: no table for this group (the appendix shows near-perfect humans in figures only).")
        blocks.append(Block("p", (
            f"Change with assistance (assisted minus unassisted, same humans and env seeds), mean ± std over every "
            f"(training seed, human) pair as the paper aggregates; CI: {int(CONFIDENCE * 100)} % bootstrap interval of "
            f"the mean over training seeds; IQM: interquartile mean. Seeds: {_seeds_text(t['seeds'], names)}. "
            f"Humans per seed: {per_seed}; paired episodes per human: {episodes}. Preset: assistants "
            f"{'; '.join(t['preset']['assistants']) or '?'}; humans {'; '.join(t['preset']['humans']) or '?'}. "
            f"{paper_note} Intent met (not in the paper): change in {INTENT_MET_TEXT.get(t['intent'], 'the intent criterion')}, "
            "the human's own goal, which progress does not show.")))
        header = ["Method", "", *(f"{HEADERS[m]} {UP if HIGHER_IS_BETTER[m] else DOWN}" for m in t["metrics"]), "from"]
        rows = []
        for r in t["rows"]:
            rows.append([Cell([r["name"]]), Cell(["ours"]), *(_ours_change(r["cells"][m], m, r["ran"]) for m in t["metrics"]),
                         Cell([short(r["sources"])], title=_sources_title(r["sources"]))])
            if t["paper_table"]:
                rows.append([Cell([""]), Cell(["paper"]),
                             *(_paper_change(r["cells"][m]["paper"]) for m in t["metrics"]),
                             Cell([f"`{t['paper_table']}`" if any(r["cells"][m]["paper"] for m in t["metrics"])
                                   else "-"])])
        blocks.append(Block("table", table=Table(header, rows)))
        if t.get("unsafe"):
            blocks.append(Block("p", (
                f"{UNSAFE} **Safety rule broken** by {', '.join(names[m] for m in t['unsafe'])}: with assistance these "
                f"humans collide or leave the track more often than unassisted by more than {SAFETY_MARGIN:.2f} (a share of "
                "episodes), on the mean over every (training seed, human) value.")))
    return blocks


def _f1_cell(cell: dict[str, Any] | None, ran: bool) -> Cell:
    if cell is None:
        return Cell(["not run" if not ran else "-"])
    per_intent = ", ".join(f"{i} {v:.3f}" for i, v in cell["per_intent"].items() if v is not None)
    return Cell([f"{cell['mean']:.3f} ± {cell['std']:.3f}", f"CI {cell['ci_text']}",
                 f"{cell['n_seeds']} seed{'s' if cell['n_seeds'] != 1 else ''}" + (f"; {per_intent}" if per_intent
                                                                                    else "")],
                title=_sources_title(cell["sources"]))


def f1_blocks(tables: Sequence[dict[str, Any]]) -> list[Block]:
    blocks = []
    for t in tables:
        blocks.append(Block("h3", f"{t['track']}, {t['pair']}"))
        note = ""
        if t["no_intent_estimate"]:
            note = f" {', '.join(t['no_intent_estimate'])}: no intent estimate (the method infers none)."
        blocks.append(Block("p", (
            "Per-step intent classification F1 (macro over the pair's intents, per-class F1 after the seeds) of the "
            "assisted evaluation episodes: on the humans the assistants were trained with, and on held-out "
            f"populations (`d2a eval --humans`). Mean ± std over training seeds. Paired episodes per human: "
            f"{', '.join(map(str, t['episodes_per_human'])) or '?'}. Preset: {'; '.join(t['preset']) or '?'}. "
            f"Paper: `{t['paper_table']}` (training humans).{note}")))
        rows = []
        for r in t["rows"]:
            ref = r["paper"]
            paper_cell = Cell([f"{ref['mean']:.2f} ± {ref['std']:.3f}"], title=ref["table"]) if ref \
                else Cell(["not in the paper"])
            rows.append([Cell([r["name"]]), _f1_cell(r["training"], r["ran"]), _f1_cell(r["heldout"], r["ran"]),
                         paper_cell, Cell([short(r["sources"])], title=_sources_title(r["sources"]))])
        blocks.append(Block("table", table=Table(["Method", "training humans", "held-out humans",
                                                  "paper (training)", "from"], rows)))
    return blocks


def _swap_cell(cell: dict[str, Any] | None) -> Cell:
    if cell is None:
        return Cell(["-"])
    if cell["mean"] is None:
        recovery = f"never ({cell['seeds_total']} seed{'s' if cell['seeds_total'] != 1 else ''})"
        lines = [recovery]
    else:
        lines = [f"{cell['mean']:.1f} ± {cell['std']:.1f} s",
                 f"CI {cell['ci_text']}; recovered in {cell['seeds_recovered']}/{cell['seeds_total']} seeds"]
    median = cell["median_trial_recovery_s"]
    lines.append(f"trials: median {median:.1f} s, {cell['recovered_trials']}/{cell['trials']} recovered"
                 if median is not None else f"trials: {cell['recovered_trials']}/{cell['trials']} recovered")
    changes = []
    for m in SWAP_METRICS:
        v = cell["metrics"][m]
        if v["mean"] is not None:
            changes.append(f"Δ{HEADERS[m].split(' ')[0].lower()} {_num(v['mean'], DECIMALS[m])}"
                           + (f" {IMPROVED}" if v["improved"] else ""))
    lines.append(", ".join(changes))
    return Cell(lines, title=_sources_title(cell["sources"]))


def swap_blocks(tables: Sequence[dict[str, Any]]) -> list[Block]:
    blocks = []
    for t in tables:
        blocks.append(Block("h3", f"{t['track']}, {t['pair']}"))
        trials = ", ".join(map(str, t["trials_per_direction"])) or "?"
        blocks.append(Block("p", (
            f"Recovery: time after the swap until the mean intent accuracy (over trials) reaches {t['recovery_level']} "
            f"and holds it for {t['hold_s']} s; mean ± std over training seeds that recovered. Trials per direction "
            f"and seed: {trials}; swap window {t['window_s']} s; preset: {'; '.join(t['preset']) or '?'}. "
            f"Δ: paired change with assistance over the trials "
            f"(mean over seeds). Paper: `sec:intent_compare` gives no table; its text reports recovery to > 90 % "
            f"within 4-8 s (Dream2Assist, hairpin pass-stay).")))
        rows = []
        for r in t["rows"]:
            ref = r["paper"]
            paper_cell = Cell([f"{ref['recovery_s'][0]:g}-{ref['recovery_s'][1]:g} s (text)"], title=ref["note"]) \
                if ref else Cell(["not in the paper"])
            rows.append([Cell([r["name"]]), Cell([", ".join(map(str, r["seeds"]))]),
                         *(_swap_cell(r["directions"].get(d)) for d in t["directions"]), paper_cell,
                         Cell([short(r["sources"])], title=_sources_title(r["sources"]))])
        blocks.append(Block("table", table=Table(["Method", "seeds", *t["directions"], "paper", "from"], rows)))
    return blocks


def document(doc: dict[str, Any], plots: Sequence[Plot]) -> list[Block]:
    """Every block of the report, in order."""
    tables = doc["tables"]
    blocks = [Block("h1", "Dream2Assist reproduction: results"),
              Block("p", doc["summary"]),
              Block("p", (f"Statistics: mean ± std as the paper reports; CI: {int(CONFIDENCE * 100)} % percentile "
                          f"bootstrap (`scipy.stats.bootstrap`, {BOOTSTRAP_RESAMPLES} resamples, seed "
                          f"{BOOTSTRAP_SEED}) of the mean over training seeds, shown as \"n/a (k seeds)\" below "
                          f"{MIN_SEEDS} seeds; IQM: "
                          "`scipy.stats.trim_mean(x, 0.25)`. Marks: ▲ better than the unassisted humans (the paper's "
                          "blue), **bold** the best method (the paper's bold); interventions are not marked, as in the "
                          "paper; the paper's values are marked by the same rule among its own rows. `from`: the "
                          "artifacts a row's cells were computed from "
                          "(first 12 characters of their ids; all ids are listed at the end)."))]
    blocks.append(Block("h2", "1. Change with assistance (Table 1, appendix tab:pass_stay and tab:left_right)"))
    blocks += change_blocks(tables["change"]) or [Block("p", "No evaluation to report: run `d2a eval`.")]
    if tables["not_run"]:
        items = "; ".join(f"{n['track']} {n['pair']} (paper `{n['paper_table']}`): `{n['command']}`"
                          for n in tables["not_run"])
        blocks.append(Block("p", f"Not run here, reported by the paper: {items}."))
    blocks.append(Block("h2", "2. Intent inference F1 (tab:f1-scores)"))
    blocks += f1_blocks(tables["f1"]) or [Block("p", "No evaluation to report: run `d2a eval`.")]
    blocks.append(Block("h2", "3. Intent swap: recovery of the intent estimate (sec:intent_compare)"))
    blocks += swap_blocks(tables["intent_swap"]) or [
        Block("p", "No intent-swap artifact: run `d2a intent-swap --track T --pair P --baseline dreamer`.")]
    blocks.append(Block("h2", "4. Figures"))
    for plot in plots:
        blocks.append(Block("h3", plot.title))
        blocks.append(Block("figure", plot=plot))
    for kind, why in doc["skipped"].items():
        blocks.append(Block("p", f"Figure kind `{kind}` not drawn: {why}."))
    if tables.get("studies"):
        from d2a_core.report.studies import study_blocks

        blocks.append(Block("h2", "5. Studies with people (`d2a study`)"))
        blocks.append(Block("p", "Each participant's trials alone and with the assistant: the rate that met the stated "
                                 "intent by the evaluation's criterion, the rate they said they did, and the paired "
                                 "change over starts driven both ways."))
        blocks += study_blocks(tables["studies"])
    blocks.append(Block("h2", f"{6 if tables.get('studies') else 5}. Artifacts used"))
    blocks.append(Block("p", "The report artifact's inputs: exactly these."))
    blocks.append(Block("table", table=Table(["id", "kind", "aliases"], [
        [Cell([f"`{a['id']}`"]), Cell([a["kind"]]), Cell([", ".join(f"`{x}`" for x in a["aliases"]) or "-"])]
        for a in doc["artifacts"]])))
    return blocks


# ------------------------------------------------------------------------------------------ markdown
def _md_cell(cell: Cell) -> str:
    lines = [line.replace("|", "\\|") for line in cell.lines]
    if cell.bold and lines and lines[0]:
        lines[0] = f"**{lines[0]}**"
    return "<br>".join(lines)


def markdown(blocks: Sequence[Block]) -> str:
    out: list[str] = []
    for b in blocks:
        if b.kind in ("h1", "h2", "h3"):
            out.append("#" * int(b.kind[1]) + " " + b.text)
        elif b.kind == "p":
            out.append(b.text)
        elif b.kind == "table":
            t = b.table
            out.append("| " + " | ".join(t.header) + " |")
            out.append("|" + "---|" * len(t.header))
            out.extend("| " + " | ".join(_md_cell(c) for c in row) + " |" for row in t.rows)
        elif b.kind == "figure":
            p = b.plot
            out.append(f"![{p.title}](figures/{p.name}.png)")
            out.append(f"*{p.caption}* From: {short(p.sources)}. Also as [SVG](figures/{p.name}.svg).")
        out.append("")
    return "\n".join(out)


# ------------------------------------------------------------------------------------------ html
CSS = """
body { font-family: "DejaVu Sans", Arial, sans-serif; font-size: 14px; margin: 2em auto; max-width: 1200px;
       color: #222; line-height: 1.4; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em 0; font-size: 12px; }
th, td { border: 1px solid #bbb; padding: 3px 6px; vertical-align: top; text-align: left; }
th { background: #f0f0f0; }
td.improved { background: #c6d3f5; }
td .sub { color: #555; font-size: 11px; }
code { font-size: 12px; background: #f5f5f5; padding: 0 2px; }
figure { margin: 0.5em 0 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 12px; color: #444; }
"""


def _inline(text: str) -> str:
    """Escape, then the Markdown the paragraphs use: `code` and **bold**."""
    text = html.escape(text, quote=False)
    text = re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", text)


def _html_cell(cell: Cell, tag: str = "td") -> str:
    parts = []
    for k, line in enumerate(cell.lines):
        content = _inline(line)
        if k == 0 and cell.bold and line:
            content = f"<b>{content}</b>"
        parts.append(content if k == 0 else f'<span class="sub">{content}</span>')
    attrs = ' class="improved"' if cell.improved else ""
    if cell.title:
        attrs += f' title="{html.escape(cell.title)}"'
    return f"<{tag}{attrs}>" + "<br>".join(parts) + f"</{tag}>"


def to_html(blocks: Sequence[Block]) -> str:
    title = next((b.text for b in blocks if b.kind == "h1"), "report")
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           f"<title>{html.escape(title)}</title>", f"<style>{CSS}</style>", "</head>", "<body>"]
    for b in blocks:
        if b.kind in ("h1", "h2", "h3"):
            out.append(f"<{b.kind}>{_inline(b.text)}</{b.kind}>")
        elif b.kind == "p":
            out.append(f"<p>{_inline(b.text)}</p>")
        elif b.kind == "table":
            t = b.table
            out.append("<table>")
            out.append("<tr>" + "".join(f"<th>{_inline(h)}</th>" for h in t.header) + "</tr>")
            out.extend("<tr>" + "".join(_html_cell(c) for c in row) + "</tr>" for row in t.rows)
            out.append("</table>")
        elif b.kind == "figure":
            p = b.plot
            data = base64.b64encode(p.png).decode("ascii")
            out.append(f'<figure id="{html.escape(p.name)}"><img alt="{html.escape(p.title)}" '
                       f'src="data:image/png;base64,{data}">')
            out.append(f"<figcaption>{_inline(p.caption)} From: {_inline(short(p.sources))}. "
                       f'<span title="{html.escape(_sources_title(p.sources))}">(full ids)</span></figcaption>'
                       "</figure>")
    out += ["</body>", "</html>", ""]
    return "\n".join(out)
