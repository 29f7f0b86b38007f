"""`d2a train-assistant`: train Dream2Assist (or a baseline) with frozen human populations."""

from __future__ import annotations

import contextlib
from typing import Annotated, Any, Optional

import typer
from rich import box
from rich.table import Column, Table

from d2a_cli.common import (
    ConfigFileOpt,
    PresetOpt,
    RunContext,
    SetOpt,
    TrainingBars,
    before_after,
    out_console,
    with_common_options,
)
from d2a_core import config as config_mod
from d2a_core.training.methods import method_names


@with_common_options
def train_assistant(
    track: Annotated[str, typer.Option("--track", help="Track name, alias or artifact id (built by make-track).")],
    pair: Annotated[str, typer.Option("--pair", help="Intent pair the assistant tells apart: pass-stay or left-right.")],
    method: Annotated[list[str], typer.Option(
        "--method", help=f"Method to train, repeatable: {', '.join(method_names())}.")] = ["dream2assist"],  # noqa: B006
    humans: Annotated[Optional[list[str]], typer.Option(
        "--humans", help="Population of each intent of the pair, in order (id, prefix or alias) "
                         "[default: humans/<track>/<intent>]; several of one intent as A,B (the first is "
                         "its reference: expert and panel; the others add drivers).", show_default=False)] = None,
    preset: PresetOpt = "quick",
    config_file: ConfigFileOpt = None,
    overrides: SetOpt = None,
    alias: Annotated[bool, typer.Option(
        "--alias/--no-alias", help="Point assistants/<track>/<pair>/<method>/seed<k> (and assistant-runs/...) at "
                                   "this run; --no-alias for a side run (a sweep, a timing), kept as "
                                   "assistant-runs/<track>/<pair>/<method>/seed<k>/side/<run id>.")] = True,
    *,
    run: RunContext,
) -> None:
    """Train assistants with the pair's frozen populations; store checkpoints evaluated on a paired panel."""
    from d2a_core.run_inputs import parse_pair
    from d2a_core.training.assistant import train_assistant as train
    from d2a_core.training.methods import get_method

    parse_pair(pair)  # a bad pair or method is a usage error before anything loads
    for name in method:
        get_method(name)
    resolved = config_mod.load(preset, config_file, overrides or [], pair=pair)
    store = run.store()
    results = []
    with contextlib.ExitStack() as cleanup:
        bars = TrainingBars(cleanup, resolved.config.assistant.env_steps, return_label="r^A")
        for name in method:
            result = train(store, track, pair, name, resolved, run.seed, humans=humans, device=run.device,
                           progress=bars.reporter(name), move_aliases=alias)
            bars.finish(name, result, "assistant")
            results.append(result)

    def render(r: dict[str, Any]) -> None:
        for res in r["assistants"]:
            intents = res["intents"]
            # one row per checkpoint and intent, so the table fits an 80-column terminal
            table = Table(*(Column(name, no_wrap=True) for name in (
                              "id", "step", "F1", "intent", "gain w", "ratio e", "crit. w", "crit. e")),
                          box=box.SIMPLE_HEAD,
                          title=f"assistants/{res['track']}/{res['pair']}/{res['method']}/seed{res['seed']}",
                          caption="gain w: progress gained by the weak drivers (m); ratio e: the expert's progress "
                                  "assisted / unassisted; crit.: the intent's own criterion, unassisted → assisted "
                                  "(w: weak drivers, e: expert)")
            for c in res["checkpoints"]:
                m = c["metrics"]
                f1 = m.get("intent_f1")
                for k, i in enumerate(intents):
                    first = k == 0
                    table.add_row(c["id"][:8] if first else "", str(c["env_step"]) if first else "",
                                  ("-" if f1 is None else f"{f1:.3f}") if first else "", i,
                                  _num(m.get(f"{i}/weak/progress_gain")), _num(m.get(f"{i}/expert/progress_ratio"), 3),
                                  _change(m, f"{i}/weak"), _change(m, f"{i}/expert"),
                                  end_section=k == len(intents) - 1)
            out_console.print(table)
            if res.get("time_shares"):
                shares = ", ".join(f"{k} {v:.0%}" for k, v in res["time_shares"].items())
                out_console.print(f"wall time: {shares}")

    run.emit({"assistants": results}, render)


def _change(metrics: dict[str, Any], key: str) -> str:
    """The intent criterion unassisted → assisted (the rate a driver of that intent is judged by)."""
    return before_after(metrics.get(f"{key}/criterion_unassisted"), metrics.get(f"{key}/criterion_assisted"))


def _num(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
