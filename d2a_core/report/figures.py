"""The report's figures (matplotlib, Agg, no pyplot): the same inputs give byte-identical PNG and SVG.

Five kinds, each a function of collected artifacts returning `Plot`s (or nothing, with the
reason in `skipped`):

- `change_bars`: per track, pair and intent, each human's change with assistance in the five
  table metrics, imperfect humans 1-5 then the near-perfect ones (the paper's "pass complete" /
  "stay complete" figures); bars are means over training seeds, whiskers +-1 std over seeds.
- `learning_curves`: the humans' training curves (progress, return) per population, and the
  assistants' (progress, return, per-episode intent accuracy) per method, mean over seeds with
  the min-max band.
- `time_traces`: one assisted episode per intent (the paper's time-trace figure): the inferred
  intent as background colour, the ego-opponent gap, speed, and the assistant's steering and
  acceleration (the human's dotted), from the episode's MCAP log (or `steps.npz` without one).
- `tsne`: t-SNE (scikit-learn, exact, fixed seed, one BLAS thread) of the assistants' latent states
  (`latents.npz`), one panel per method, coloured by the true intent.
- `swap_accuracy`: intent accuracy against time since an intent swap, per direction and method.

Determinism: fixed font (DejaVu Sans, shipped with matplotlib), `svg.hashsalt`, glyphs as paths,
no date or software version in the files, fixed dpi, seeded subsampling and t-SNE.
"""

from __future__ import annotations

import io
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from d2a_core.report import paper
from d2a_core.report.collect import Collected, Evaluation, method_key
from d2a_core.report.tables import HEADERS, METRICS

STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 8,
    "axes.titlesize": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "svg.hashsalt": "d2a-report",
    "svg.fonttype": "path",
    "figure.dpi": 100,
    "savefig.dpi": 100,
    "path.simplify": True,
}
METHOD_COLORS = {"dreamer": "#1f77b4", "dreamer-ail": "#9467bd", "dream2assist": "#d62728",
                 "dream2assist+a": "#ff7f0e", "dream2assist+a-r": "#8c564b", "no-rssm": "#2ca02c"}
EXTRA_COLORS = ("#17becf", "#bcbd22", "#e377c2", "#7f7f7f")
INTENT_COLORS = ("#1b9e77", "#7570b3")
TSNE_POINTS = 500
TSNE_SEED = 0
TRACE_HUMAN = 3
"""The imperfect human whose episode the time trace shows (the middle of 1-5), when present."""


@dataclass
class Plot:
    name: str  # file stem under figures/
    kind: str
    title: str
    caption: str
    sources: list[str]
    png: bytes = b""
    svg: bytes = b""


@dataclass
class Figures:
    plots: list[Plot] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)  # kind -> why nothing was drawn


def method_color(method: str) -> str:
    if method in METHOD_COLORS:
        return METHOD_COLORS[method]
    return EXTRA_COLORS[sum(map(ord, method)) % len(EXTRA_COLORS)]


def render(fig: Figure) -> tuple[bytes, bytes]:
    """PNG and SVG bytes of a figure, without dates or version strings."""
    png, svg = io.BytesIO(), io.BytesIO()
    with matplotlib.rc_context(STYLE):
        fig.savefig(png, format="png", metadata={"Software": None})
        fig.savefig(svg, format="svg", metadata={"Date": None, "Creator": None})
    return png.getvalue(), svg.getvalue()


def _figure(width: float, height: float) -> Figure:
    with matplotlib.rc_context(STYLE):
        return Figure(figsize=(width, height), layout="constrained")


def _finish(plot: Plot, fig: Figure) -> Plot:
    with matplotlib.rc_context(STYLE):
        plot.png, plot.svg = render(fig)
    return plot


def _training_evaluations(data: Collected, track: str, pair: str) -> list[Evaluation]:
    return [e for e in data.evaluations if (e.track, e.pair, e.heldout) == (track, pair, False)]


# ------------------------------------------------------------------------------------ change bars
def change_bars(data: Collected) -> list[Plot]:
    plots = []
    for track, pair in data.pairs():
        evaluations = _training_evaluations(data, track, pair)
        if not evaluations:
            continue
        for intent in pair.split("-"):
            plot = _change_bars(track, pair, intent, evaluations)
            if plot is not None:
                plots.append(plot)
    return plots


def _change_bars(track: str, pair: str, intent: str, evaluations: Sequence[Evaluation]) -> Plot | None:
    # per method, per human (group, number): {seed: delta}
    values: dict[str, dict[tuple[int, int], dict[str, list[float]]]] = defaultdict(lambda: defaultdict(
        lambda: defaultdict(list)))
    sources = set()
    for e in evaluations:
        for h in e.result.get("humans", []):
            if h["intent"] != intent:
                continue
            key = (0 if h["group"] == "imperfect" else 1, h["number"])
            for m in METRICS:
                if h["delta"].get(m) is not None:
                    values[e.method][key][m].append(h["delta"][m])
            sources.add(e.id)
    if not values:
        return None
    methods = sorted(values, key=method_key)
    humans = sorted({k for per in values.values() for k in per})
    imperfect = sum(1 for g, _ in humans if g == 0)
    labels = [str(n) if g == 0 else str(imperfect + n) for g, n in humans]
    fig = _figure(2.6 * len(METRICS), 2.9)
    axes = fig.subplots(1, len(METRICS))
    width = 0.8 / len(methods)
    x = np.arange(len(humans))
    for ax, m in zip(axes, METRICS):
        for j, method in enumerate(methods):
            means = [np.mean(values[method][k][m]) if values[method][k][m] else np.nan for k in humans]
            stds = [np.std(values[method][k][m]) if len(values[method][k][m]) > 1 else 0.0 for k in humans]
            ax.bar(x + (j - (len(methods) - 1) / 2) * width, means, width, yerr=stds, capsize=1.5,
                   color=method_color(method), label=paper.paper_name(method), error_kw={"linewidth": 0.6})
        ax.axhline(0, color="black", linewidth=0.6)
        if 0 < imperfect < len(humans):
            ax.axvline(imperfect - 0.5, color="grey", linestyle="--", linewidth=0.7)
        ax.set_xticks(x, labels)
        ax.set_title(f"change in {HEADERS[m].lower()}")
    fig.supxlabel("human: 1-%d imperfect%s" % (imperfect, ", then near-perfect" if imperfect < len(humans) else ""))
    axes[0].legend(fontsize=7, loc="best")
    title = f"{track}, {pair}: {intent} humans, change with assistance"
    fig.suptitle(title)
    seeds = sorted({e.seed for e in evaluations})
    caption = (f"Each human's change with assistance (assisted minus unassisted, same episodes) for {intent} "
               f"humans on {track} ({pair}); bars: mean over training seeds {', '.join(map(str, seeds))}, "
               "whiskers: +-1 std over seeds; humans 1-5 imperfect, then near-perfect.")
    return _finish(Plot(f"change-{track}-{pair}-{intent}", "change_bars", title, caption, sorted(sources)), fig)


# --------------------------------------------------------------------------------- learning curves
def _mean_band(curves: Sequence[Sequence[dict[str, Any]]], key: str) -> tuple[np.ndarray, ...] | None:
    by_step: dict[float, list[float]] = defaultdict(list)
    for curve in curves:
        for row in curve:
            v = row.get(key)
            if v is not None and np.isfinite(v) and row.get("env_step") is not None:
                by_step[row["env_step"]].append(float(v))
    if not by_step:
        return None
    steps = np.array(sorted(by_step), dtype=float)
    return (steps, np.array([np.mean(by_step[s]) for s in steps]), np.array([np.min(by_step[s]) for s in steps]),
            np.array([np.max(by_step[s]) for s in steps]))


def _curve_panel(ax, series: Sequence[tuple[str, str, Sequence[Sequence[dict]]]], key: str, title: str) -> bool:
    drawn = False
    for label, color, curves in series:
        band = _mean_band(curves, key)
        if band is None:
            continue
        steps, mean, low, high = band
        ax.plot(steps, mean, color=color, label=label, linewidth=1.2)
        if len(curves) > 1:
            ax.fill_between(steps, low, high, color=color, alpha=0.2, linewidth=0)
        drawn = True
    ax.set_title(title)
    ax.set_xlabel("env steps")
    return drawn


def learning_curves(data: Collected) -> list[Plot]:
    plots = []
    for track in sorted({p.track for p in data.populations}):
        pops = [p for p in data.populations if p.track == track]
        series = [(f"{p.intent} (seed {p.seed})", INTENT_COLORS[k % 2] if len(pops) <= 2 else method_color(p.intent),
                   [p.curve]) for k, p in enumerate(pops)]
        fig = _figure(8.0, 2.8)
        axes = fig.subplots(1, 2)
        ok = _curve_panel(axes[0], series, "episode/progress_m", "episode progress (m)")
        ok |= _curve_panel(axes[1], series, "episode/return", "episode return (human objective)")
        if not ok:
            continue
        axes[0].legend(fontsize=7)
        title = f"{track}: learning curves of the human populations"
        fig.suptitle(title)
        caption = (f"Training curves of the synthetic human populations on {track} (means over the episodes "
                   "ended since the previous log point); their checkpoints are the humans under test.")
        plots.append(_finish(Plot(f"curves-humans-{track}", "learning_curves", title, caption,
                                  sorted(p.id for p in pops)), fig))
    for track, pair in data.pairs():
        runs = [r for r in data.runs if (r.track, r.pair) == (track, pair)]
        if not runs:
            continue
        methods = sorted({r.method for r in runs}, key=method_key)
        series = [(f"{paper.paper_name(m)} ({sum(r.method == m for r in runs)} seed"
                   f"{'s' if sum(r.method == m for r in runs) != 1 else ''})", method_color(m),
                   [r.curve for r in runs if r.method == m]) for m in methods]
        keys = [("episode/progress_m", "episode progress (m)"), ("episode/return", "episode return (human objective)")]
        if any("episode/intent_accuracy" in row for r in runs for row in r.curve):
            keys.append(("episode/intent_accuracy", "per-step intent accuracy"))
        fig = _figure(3.4 * len(keys), 2.8)
        axes = fig.subplots(1, len(keys))
        ok = False
        for ax, (key, label) in zip(axes, keys):
            ok |= _curve_panel(ax, series, key, label)
        if not ok:
            continue
        axes[0].legend(fontsize=7)
        title = f"{track}, {pair}: learning curves of the assistants"
        fig.suptitle(title)
        caption = (f"Assistant training on {track} ({pair}): mean over training seeds, band min-max over seeds; "
                   "episodes are shared-control episodes with humans drawn from both populations.")
        plots.append(_finish(Plot(f"curves-assistants-{track}-{pair}", "learning_curves", title, caption,
                                  sorted(r.id for r in runs)), fig))
    return plots


# ------------------------------------------------------------------------------------ time traces
def _npz(data: Collected, art_id: str, name: str) -> dict[str, np.ndarray] | None:
    if name not in data.store.get(art_id).files:
        return None
    with np.load(io.BytesIO(data.store.read_bytes(art_id, name))) as z:
        return {k: z[k] for k in z.files}


def _trace_choice(evaluations: Sequence[Evaluation], intent: str) -> tuple[Evaluation, int, dict] | None:
    """The evaluation (dream2assist first, lowest seed), the assisted row index and row to show."""
    ranked = sorted(evaluations, key=lambda e: (e.method != "dream2assist", method_key(e.method), e.seed))
    for e in ranked:
        humans = [h for h in e.result.get("humans", []) if h["intent"] == intent and h["group"] == "imperfect"]
        if not humans:
            continue
        numbers = sorted(h["number"] for h in humans)
        number = TRACE_HUMAN if TRACE_HUMAN in numbers else numbers[len(numbers) // 2]
        human = next(h for h in humans if h["number"] == number)
        # eval rows carry `human` as an index into result.humans
        index = e.result["humans"].index(human)
        rows = [(k, r) for k, r in enumerate(e.assisted) if r.get("human") == index]
        if rows:
            k, row = min(rows, key=lambda kr: kr[1].get("seed", 0))
            return e, k, dict(row, number=number, performance=human.get("performance"))
    return None


def _intent_spans(ax, times: np.ndarray, inferred: np.ndarray) -> None:
    """Background colour by the inferred intent (index; -1 for none)."""
    if not len(times):
        return
    dt = float(np.median(np.diff(times))) if len(times) > 1 else 0.1
    start = 0
    for k in range(1, len(times) + 1):
        if k == len(times) or inferred[k] != inferred[start]:
            if inferred[start] >= 0:
                ax.axvspan(times[start] - dt / 2, times[k - 1] + dt / 2, color=INTENT_COLORS[int(inferred[start]) % 2],
                           alpha=0.15, linewidth=0)
            start = k


def time_traces(data: Collected) -> list[Plot]:
    from d2a_core.sim.episode_log.reader import read_episode  # reads MCAP files only

    plots = []
    for track, pair in data.pairs():
        evaluations = _training_evaluations(data, track, pair)
        intents = pair.split("-")
        for intent in intents:
            choice = _trace_choice(evaluations, intent)
            if choice is None:
                continue
            e, k, row = choice
            log = f"episodes/assisted/human{row['human']:03d}-seed{row['seed']}.mcap"
            panels: list[tuple[str, np.ndarray, np.ndarray | None]] = []
            if log in e.files:
                episode = read_episode(data.store.path(e.id, log))
                ego, assistant = episode.state.get("ego", {}), episode.state.get("assistant", {})
                times = np.asarray(episode.times, float)
                probs = [assistant.get(f"intent_probs.{i}") for i in intents]
                if all(p is not None for p in probs):
                    stacked = np.stack([np.asarray(p, float) for p in probs], axis=1)
                    inferred = np.where(np.isfinite(stacked).all(axis=1), np.nanargmax(np.nan_to_num(stacked, nan=-1),
                                                                                       axis=1), -1)
                else:
                    inferred = np.full(len(times), -1)
                for name, key, human_key in (("ego - opponent gap ds (m)", "ds", None), ("speed (m/s)", "speed", None),
                                             ("steering", "assistant_action.steer", "human_action.steer"),
                                             ("acceleration", "assistant_action.accel", "human_action.accel")):
                    if key in ego:
                        panels.append((name, np.asarray(ego[key], float),
                                       np.asarray(ego[human_key], float) if human_key in ego else None))
                source = f"the episode's MCAP log ({log})"
            else:
                steps = _npz(data, e.id, "steps.npz")
                if steps is None:
                    continue
                mask = steps["episode"] == k
                dt = float(data.store.get(e.id).config.get("env", {}).get("dt", 0.1))
                times = np.arange(int(mask.sum())) * dt
                inferred = steps["y_hat"][mask].astype(int) if "y_hat" in steps else np.full(len(times), -1)
                panels = [("steering", steps["assistant_action"][mask, 0], steps["human_action"][mask, 0]),
                          ("acceleration", steps["assistant_action"][mask, 1], steps["human_action"][mask, 1])]
                source = "steps.npz (this evaluation has no MCAP logs: no gap or speed panels)"
            if not panels:
                continue
            fig = _figure(7.5, 1.5 * len(panels) + 0.6)
            axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
            for ax, (name, values, human) in zip(axes, panels):
                _intent_spans(ax, times, inferred)
                ax.plot(times[:len(values)], values, color="black", linewidth=1.0,
                        label="assistant" if human is not None else None)
                if human is not None:
                    ax.plot(times[:len(human)], human, color="grey", linewidth=0.9, linestyle=":", label="human")
                if name.startswith("ego"):
                    ax.axhline(0, color="grey", linewidth=0.6)
                ax.set_ylabel(name, fontsize=7)
            axes[-1].set_xlabel("time (s)")
            handles = [Patch(color=INTENT_COLORS[j % 2], alpha=0.3, label=f"inferred: {i}")
                       for j, i in enumerate(intents)]
            if any(h is not None for _, _, h in panels):
                handles += axes[-1].get_legend_handles_labels()[0]
            axes[0].legend(handles=handles, fontsize=7, loc="upper left", ncol=len(handles))
            title = (f"{track}, {pair}: {paper.paper_name(e.method)} (seed {e.seed}) with imperfect {intent} "
                     f"human {row['number']}")
            fig.suptitle(title)
            outcome = ", ".join(f"{m} {row[m]:.2f}" for m in ("progress_m", "collision", "intervention")
                                if isinstance(row.get(m), (int, float)))
            caption = (f"One assisted episode (env seed {row['seed']}; {outcome}). Background: the intent the "
                       f"assistant infers at each step (the true intent is {intent}); lines: the assistant's "
                       f"actions, dotted: the human's. From {source}.")
            plots.append(_finish(Plot(f"trace-{track}-{pair}-{intent}", "time_traces", title, caption, [e.id]), fig))
    return plots


# ------------------------------------------------------------------------------------------ t-SNE
def tsne(data: Collected) -> list[Plot]:
    from sklearn.manifold import TSNE
    from threadpoolctl import threadpool_limits  # a dependency of scikit-learn

    plots = []
    for track, pair in data.pairs():
        chosen: dict[str, tuple[Evaluation, dict[str, np.ndarray]]] = {}
        for e in sorted(_training_evaluations(data, track, pair), key=lambda e: (method_key(e.method), e.seed)):
            if e.method in chosen or "latents.npz" not in e.files:
                continue
            latents = _npz(data, e.id, "latents.npz")
            if latents is not None and len(latents.get("features", ())) >= 10:
                chosen[e.method] = (e, latents)
        if not chosen:
            continue
        intents = pair.split("-")
        fig = _figure(3.6 * len(chosen), 3.4)
        axes = np.atleast_1d(fig.subplots(1, len(chosen)))
        for ax, (method, (e, latents)) in zip(axes, chosen.items()):
            features = np.asarray(latents["features"], np.float64)
            labels = np.asarray(latents["label"], int)
            rng = np.random.default_rng(TSNE_SEED)
            keep = np.sort(rng.choice(len(features), TSNE_POINTS, replace=False)) if len(features) > TSNE_POINTS \
                else np.arange(len(features))
            x = features[keep]
            perplexity = float(min(30.0, max(2.0, (len(x) - 1) / 3)))
            # one BLAS thread: the float sums, and so the bytes, do not depend on the core count
            with threadpool_limits(limits=1):
                embedded = TSNE(n_components=2, perplexity=perplexity, init="pca", method="exact",
                                random_state=TSNE_SEED).fit_transform(x)
            for j, intent in enumerate(intents):
                mask = labels[keep] == j
                ax.scatter(embedded[mask, 0], embedded[mask, 1], s=4, color=INTENT_COLORS[j % 2], label=intent,
                           linewidths=0)
            ax.set_title(f"{paper.paper_name(method)} (seed {e.seed}, {len(x)} states)")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.legend(fontsize=7, markerscale=3, title="true intent", title_fontsize=7)
        title = f"{track}, {pair}: t-SNE of the assistants' latent states"
        fig.suptitle(title)
        caption = ("t-SNE (scikit-learn, exact, PCA init, seed 0; at most %d states sampled with a fixed seed) of the "
                   "assistant's latent features along assisted evaluation episodes, coloured by the true intent of "
                   "the human (the paper's fig:t-sne)." % TSNE_POINTS)
        plots.append(_finish(Plot(f"tsne-{track}-{pair}", "tsne", title, caption,
                                  sorted(e.id for e, _ in chosen.values())), fig))
    return plots


# ------------------------------------------------------------------------------- intent-swap curves
def swap_accuracy(data: Collected) -> list[Plot]:
    plots = []
    for track, pair in data.pairs():
        swaps = [s for s in data.swaps if (s.track, s.pair) == (track, pair)]
        if not swaps:
            continue
        intents = pair.split("-")
        directions = [f"{intents[0]}-to-{intents[1]}", f"{intents[1]}-to-{intents[0]}"]
        fig = _figure(8.0, 2.9)
        axes = fig.subplots(1, 2, sharey=True)
        drawn = False
        level = swaps[0].result.get("recovery_level")
        for ax, d in zip(axes, directions):
            for method in sorted({s.method for s in swaps}, key=method_key):
                curves = [s.result.get("directions", {}).get(d) for s in swaps if s.method == method]
                curves = [c for c in curves if c]
                by_time: dict[float, list[float]] = defaultdict(list)
                for c in curves:
                    for t, a in zip(c["time_s"], c["accuracy"]):
                        if a is not None:
                            by_time[round(float(t), 6)].append(float(a))
                if not by_time:
                    continue
                times = np.array(sorted(by_time))
                mean = np.array([np.mean(by_time[t]) for t in times])
                ax.plot(times, mean, color=method_color(method), linewidth=1.2,
                        label=f"{paper.paper_name(method)} ({len(curves)} seed{'s' if len(curves) != 1 else ''})")
                if len(curves) > 1:
                    ax.fill_between(times, [min(by_time[t]) for t in times], [max(by_time[t]) for t in times],
                                    color=method_color(method), alpha=0.2, linewidth=0)
                drawn = True
            ax.axvline(0, color="black", linewidth=0.7)
            if level is not None:
                ax.axhline(level, color="grey", linestyle="--", linewidth=0.7)
            ax.set_ylim(-0.02, 1.02)
            ax.set_title(d)
            ax.set_xlabel("time since the swap (s)")
        if not drawn:
            continue
        axes[0].set_ylabel("intent accuracy (current intent)")
        axes[0].legend(fontsize=7, loc="lower left")
        title = f"{track}, {pair}: intent accuracy around an intent swap"
        fig.suptitle(title)
        caption = ("Per-step accuracy of the inferred intent against the current true intent, by time since the human "
                   "was swapped for the comparably trained human of the other intent; mean over trials, then over "
                   f"training seeds (band min-max over seeds); dashed: the recovery level {level}.")
        plots.append(_finish(Plot(f"swap-{track}-{pair}", "swap_accuracy", title, caption,
                                  sorted(s.id for s in swaps)), fig))
    return plots


KINDS = {
    "change_bars": (change_bars, "no evaluation: run d2a eval"),
    "learning_curves": (learning_curves, "no population or assistant-run curves: run d2a train-humans / "
                                         "d2a train-assistant"),
    "time_traces": (time_traces, "no assisted evaluation episode with a log: run d2a eval"),
    "tsne": (tsne, "no evaluation holds latents.npz (the assistant's latent states; written by d2a eval since "
                   "it records them): rerun d2a eval"),
    "swap_accuracy": (swap_accuracy, "no intent-swap artifact: run d2a intent-swap"),
}


def make_figures(data: Collected) -> Figures:
    out = Figures()
    for kind, (make, why) in KINDS.items():
        plots = make(data)
        if plots:
            out.plots.extend(plots)
        else:
            out.skipped[kind] = why
    return out
