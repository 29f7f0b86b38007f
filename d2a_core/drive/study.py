"""A small study: one participant drives a protocol's trials in one window, with and without the
assistant, the intent asked before each trial (or set by the protocol) and checked after it.

A protocol is a YAML file:

    assistant: assistants/straightaway/pass-stay/dream2assist/seed0   # needed by assisted trials
    track: straightaway              # optional with an assistant (its own track)
    seconds: 60                      # optional: end each trial after this many race seconds
    trials:                          # in the order driven
      - {intent: ask, assisted: false, seed: 1}
      - {intent: ask, assisted: true, seed: 1}       # the same start with the assistant: a pair
      - {intent: stay, assisted: true, seed: 2, script: keys/stay.yaml, answers: [y]}

`intent: ask` asks the participant before the trial (keys P pass, S stay; L, R on a left-right
assistant); a named intent is told to them instead. After each trial they answer whether they did
what they meant (Y/N). `script` and `answers` make a trial scripted (demos, tests): its key presses
and its answers to the questions, in order (paths relative to the protocol file).

A fair comparison of a person with and without the assistant is paired, as `d2a eval` pairs
synthetic drivers: the same start and opponent (`seed`) driven both ways with the same stated
intent. The study table compares those pairs (`paired`) beside every trial's outcome.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from d2a_core.artifacts import Store
from d2a_core.drive.script import load_script, read_yaml_file
from d2a_core.errors import UsageError

STUDY_KIND = "study"
INTENT_KEYS = {"pass": "p", "stay": "s", "left": "l", "right": "r"}


class Trial(BaseModel):
    model_config = ConfigDict(extra="forbid")

    intent: str = Field(description="'ask', or the intent the participant is told to follow")
    assisted: bool
    seed: int = Field(0, ge=0)
    script: Optional[str] = None
    answers: list[str] = Field(default_factory=list)


class Protocol(BaseModel):
    model_config = ConfigDict(extra="forbid")

    assistant: Optional[str] = None
    track: Optional[str] = None
    seconds: Optional[float] = Field(None, gt=0)
    trials: list[Trial] = Field(min_length=1)


def load_protocol(path: Path) -> Protocol:
    """The protocol at `path`; a wrong field names the file and the field."""
    data = read_yaml_file(path, "study protocol")
    try:
        protocol = Protocol.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise UsageError(f"study protocol {path}: field {where!r}: {first['msg']}") from None
    if any(t.assisted for t in protocol.trials) and protocol.assistant is None:
        raise UsageError(f"study protocol {path}: field 'assistant' is needed by its assisted trials")
    return protocol


def _intents_offered(store: Store, protocol: Protocol) -> tuple[str, ...]:
    if protocol.assistant is None:
        return ("pass", "stay")
    labels = store.get(protocol.assistant).labels
    pair = str(labels.get("pair", "pass-stay"))
    return tuple(pair.split("-"))


def run_study(store: Store, protocol_path: Path, participant: str, config: Any, realtime: bool = True,
              device: str = "cpu") -> dict[str, Any]:
    """Drive every trial of the protocol at `protocol_path` as `participant`; store each drive and
    the study (its table per participant). Returns the study's summary with its `id`."""
    from d2a_core.drive.controls import Controls
    from d2a_core.drive.one_drive import DriveSpec, drive
    from d2a_core.drive.window import DriveWindow
    from d2a_core.run_inputs import load_track_bundle

    protocol = load_protocol(protocol_path)
    base = Path(protocol_path).parent
    scripts = [load_script(base / t.script) if t.script else None for t in protocol.trials]
    offered = _intents_offered(store, protocol)
    for i, trial in enumerate(protocol.trials):
        if trial.intent != "ask" and trial.intent not in offered:
            raise UsageError(f"study protocol {protocol_path}: field 'trials.{i}.intent': {trial.intent!r} is not "
                             f"'ask' or one of {', '.join(offered)}")
    track_ref = protocol.track
    if track_ref is None:
        from d2a_core.run_inputs import track_of

        track_ref = track_of(store, store.resolve(protocol.assistant))
    track = load_track_bundle(store, track_ref, config.env.dt).track
    window = DriveWindow(track, Controls(), title=f"d2a study: {participant}")
    rows = []
    try:
        for i, (trial, script) in enumerate(zip(protocol.trials, scripts)):
            window.answers = list(trial.answers)
            options = {INTENT_KEYS[name]: name for name in offered}
            aid = "with the assistant" if trial.assisted else "alone"
            if trial.intent == "ask":
                intent = window.ask(f"Trial {i + 1} of {len(protocol.trials)} ({aid}): what will you do?", options)
            else:
                intent = trial.intent
                window.ask(f"Trial {i + 1} of {len(protocol.trials)} ({aid}): {intent}. Ready?", {"space": "go",
                                                                                                  "y": "go"})
            spec = DriveSpec(track=track_ref, assistant=protocol.assistant if trial.assisted else None,
                             intent=intent, seed=trial.seed, participant=participant, trial=str(i + 1),
                             max_seconds=protocol.seconds, env_of=protocol.assistant)
            result = drive(store, spec, config, script=script, realtime=realtime and script is None,
                           device=device, window=window)
            done = window.ask(f"Did you {intent}?", {"y": "yes", "n": "no"})
            rows.append({"trial": i + 1, "drive": result["id"], "intent": intent, "asked": trial.intent == "ask",
                         "assisted": trial.assisted, "seed": trial.seed, "self_report": done == "yes",
                         "met_intent": result["met_intent"], "read_as_stated": result["read_as_stated"],
                         **{k: result["metrics"][k] for k in ("progress_m", "collision", "off_track", "finished",
                                                               "intervention")}})
    finally:
        window.close()
    table = study_table(rows)
    summary = {"participant": participant, "assistant": protocol.assistant, "trials": rows, "table": table}
    with store.create(STUDY_KIND, inputs=[r["drive"] for r in rows], config=protocol.model_dump(mode="json"),
                      labels={"participant": participant, "assistant": protocol.assistant}) as writer:
        writer.add_json("study.json", summary)
    return {"id": writer.artifact.id, **summary}


def study_table(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per intent, alone and assisted: trials, objective and self-reported success, progress,
    collisions, intervention, how often the assistant read the stated intent; and per intent the
    paired trials (same seed driven both ways): the change with assistance."""
    groups = []
    for intent in sorted({r["intent"] for r in rows}):
        for assisted in (False, True):
            sel = [r for r in rows if r["intent"] == intent and r["assisted"] == assisted]
            if not sel:
                continue
            read = [r["read_as_stated"] for r in sel if r["read_as_stated"] is not None]
            groups.append({"intent": intent, "assisted": assisted, "trials": len(sel),
                           "met_intent": float(np.mean([r["met_intent"] for r in sel])),
                           "self_report": float(np.mean([r["self_report"] for r in sel])),
                           "progress_m": float(np.mean([r["progress_m"] for r in sel])),
                           "collision": float(np.mean([r["collision"] for r in sel])),
                           "intervention": float(np.mean([r["intervention"] for r in sel])),
                           "read_as_stated": float(np.mean(read)) if read else None})
    paired = []
    for intent in sorted({r["intent"] for r in rows}):
        pairs = []
        for seed in sorted({r["seed"] for r in rows if r["intent"] == intent}):
            alone = [r for r in rows if r["intent"] == intent and r["seed"] == seed and not r["assisted"]]
            helped = [r for r in rows if r["intent"] == intent and r["seed"] == seed and r["assisted"]]
            if alone and helped:
                pairs.append((alone[-1], helped[-1]))
        if pairs:
            paired.append({"intent": intent, "pairs": len(pairs),
                           "progress_change_m": float(np.mean([b["progress_m"] - a["progress_m"] for a, b in pairs])),
                           "met_intent_change": float(np.mean([b["met_intent"] - a["met_intent"] for a, b in pairs])),
                           "collision_change": float(np.mean([b["collision"] - a["collision"] for a, b in pairs]))})
    return {"groups": groups, "paired": paired}
