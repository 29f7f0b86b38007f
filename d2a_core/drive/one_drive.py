"""One drive: a person (keyboard, gamepad or a key script) at the wheel, alone or with a stored
assistant, on a stored track; the episode logged as MCAP and stored as a `drive` artifact.

The loop is evaluation's shared control with the person as the human policy: each step the person's
action `a_H` comes from the window's controls, the assistant acts on the env's observation (whose
partner slot holds `a_H` of the step before), and the car executes `clip(a_H + a_A, -1, 1)`. Steps
are paced to the env's rate (`dt`, 10 Hz) unless `realtime` is off, as for scripted drives.

A drive is an artifact of kind `drive`: inputs the track (and the assistant), config the env
sections it ran with, labels track, intent (the one the person states before driving),
assistant, participant and trial; files `drive.mcap` (the episode log, the layout evaluation logs
have, plus the person's stated intent and the assistant's estimate per step) and `drive.json`
(the episode's metrics as evaluation computes them, whether it met the stated intent, and the
share of steps the assistant read that intent). The same script, seed and assistant give the
same artifact.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from d2a_core.artifacts import Store
from d2a_core.drive.controls import Controls
from d2a_core.drive.script import KeyEvent
from d2a_core.errors import UsageError

DRIVE_KIND = "drive"


@dataclass(frozen=True)
class DriveSpec:
    """What to drive: `track` (ref; with an assistant, its own track when None), `assistant`
    (ref or None), the person's stated `intent`, the env `seed` (start and opponent), and who and
    which trial it is (labels for a study)."""

    track: str | None
    assistant: str | None
    intent: str
    seed: int = 0
    participant: str | None = None
    trial: str | None = None
    max_seconds: float | None = None
    # an artifact whose env settings a drive without an assistant takes (a study's assistant), so
    # that both halves of a pair drive the same env
    env_of: str | None = None


def _env_and_assistant(store: Store, spec: DriveSpec, config: Any, device: str):
    """The env (with its config record and track id) and the loaded assistant (or None)."""
    from d2a_core import api
    from d2a_core.objectives.rewards import INTENTS
    from d2a_core.run_inputs import ENV_SECTIONS, load_track_bundle, resolve_track, track_of

    if spec.intent not in INTENTS:
        raise UsageError(f"unknown intent {spec.intent!r}; choose from {', '.join(INTENTS)}")
    if spec.assistant is not None:
        assistant = api.load(spec.assistant, store, device=device, seed=spec.seed)
        if not isinstance(assistant, api.Assistant):
            raise UsageError(f"--assistant {spec.assistant}: {assistant.artifact.kind} artifact, not an assistant")
        if spec.intent not in assistant.intents:
            raise UsageError(f"intent {spec.intent!r} is not one of the assistant's pair "
                             f"({', '.join(assistant.intents)})")
        track_id = track_of(store, assistant.id)
        if spec.track is not None and resolve_track(store, spec.track) != track_id:
            raise UsageError(f"--track {spec.track} is not the track assistant {assistant.id[:12]} was trained on")
        env = assistant.make_env(spec.intent)
        record = {k: assistant.artifact.config[k] for k in ENV_SECTIONS if k in assistant.artifact.config}
        return env, record, track_id, assistant
    if spec.track is None:
        raise UsageError("--track is needed to drive without an assistant")
    track_id = resolve_track(store, spec.track)
    if spec.env_of is not None:
        from d2a_core.config.schema import Config

        stored = store.get(spec.env_of).config
        config = Config.model_validate({k: stored[k] for k in ENV_SECTIONS if k in stored})
    env = load_track_bundle(store, track_id, config.env.dt).env(config, spec.intent)
    record = {k: getattr(config, k).model_dump(mode="json") for k in ENV_SECTIONS}
    return env, record, track_id, None


def _with_intents(states: dict[str, dict], stated: str, belief: dict[str, float] | None) -> dict[str, dict]:
    """The ego's logged state plus the stated intent and, with an assistant, its estimate."""
    ego = dict(states["ego"], stated_intent=stated)
    if belief is not None:
        ego["intent_estimate"] = dict(belief)
    return dict(states, ego=ego)


def drive(store: Store, spec: DriveSpec, config: Any, script: list[KeyEvent] | None = None,
          realtime: bool = True, screenshot: Path | None = None, device: str = "cpu",
          window=None) -> dict[str, Any]:
    """Run one drive through the window and store it. Returns the stored drive's summary with its
    `id`. `config`: the resolved `Config` (its env sections drive a run without an assistant);
    `window`: an open `window.DriveWindow` to drive in (a study's, left open), else one is opened
    for this drive and closed after it."""
    from d2a_core.evaluation.criteria import meets_intent
    from d2a_core.evaluation.metrics import episode_metrics
    from d2a_core.sim.episode_log import EpisodeRecorder
    from d2a_core.sim.recording import scene_of, step_record
    from d2a_core.sim.shared_control import blend

    from d2a_core.drive.window import DriveWindow

    env, record, track_id, assistant = _env_and_assistant(store, spec, config, device)
    race = env.unwrapped
    dt = race.cfg.dt
    controls = Controls()
    own_window = window is None
    try:
        if own_window:
            window = DriveWindow(race.track, controls, script or ())
        else:
            window.start(race.track, controls, script or ())
    except BaseException:
        env.close()
        raise
    infos: list[dict[str, Any]] = []
    rewards: list[float] = []
    read_as_stated: list[bool] = []
    stopped = False
    started = time.monotonic()
    try:
        with store.scratch_dir("drive") as scratch:
            log_path = scratch / "drive.mcap"
            meta = {"track": race.track.name, "intent": spec.intent, "seed": spec.seed, "source": "d2a drive",
                    "assistant": assistant.id if assistant is not None else None,
                    "participant": spec.participant, "trial": spec.trial}
            recorder = EpisodeRecorder(log_path, scene_of(race.track), meta, dt)
            recorder.open()
            try:
                obs, info = env.reset(seed=spec.seed)
                race.set_partner_action(None)
                infos.append(info)
                a_assist = np.zeros(2, np.float32)
                belief: dict[str, float] | None = None
                done, t_next = False, time.monotonic()
                if assistant is not None:  # before its first step the estimate is uniform
                    belief = {name: 1.0 / len(assistant.intents) for name in assistant.intents}
                cars, states = step_record(race, info)
                recorder.log_step(info["t"], cars, _with_intents(states, spec.intent, belief))
                while not done:
                    if window.poll(float(info["t"])):
                        stopped = True
                        break
                    a_human = controls.action(dt)
                    if assistant is not None:
                        a_assist = assistant.act(obs)
                        belief = assistant.intent()
                    executed = blend(a_human, a_assist)
                    race.set_partner_action(a_human)
                    obs, reward, terminated, truncated, info = env.step(executed)
                    info = dict(info, human_action=a_human, **({"assistant_action": a_assist} if assistant else {}))
                    infos.append(info)
                    rewards.append(float(reward))
                    done = terminated or truncated or (spec.max_seconds is not None
                                                       and info["t"] >= spec.max_seconds - 1e-9)
                    cars, states = step_record(race, info, reward)
                    if belief is not None:
                        read_as_stated.append(max(belief, key=belief.get) == spec.intent)
                    recorder.log_step(info["t"], cars, _with_intents(states, spec.intent, belief))
                    poses = {name: (pose.x, pose.y, pose.yaw) for name, pose in cars.items()}
                    hud = {"t": info["t"], "speed": info["speed"], "progress": info["progress"], "gap": info["ds"],
                           "intent": spec.intent, "human_action": a_human}
                    if assistant is not None:
                        hud.update(belief=belief, assistant_action=a_assist)
                    window.draw(poses, hud)
                    if realtime:
                        t_next += dt
                        time.sleep(max(0.0, t_next - time.monotonic()))
                if stopped or len(infos) < 2:
                    recorder.abort()
                    raise UsageError("the drive was stopped before its end; nothing was stored"
                                     if stopped else "the drive ended before its first step")
                metrics = episode_metrics(infos, rewards)
                recorder.update_metadata({"outcome": {"progress_m": metrics["progress_m"],
                                                      "finished": metrics["finished"],
                                                      "collision": metrics["collision"],
                                                      "off_track": metrics["off_track"],
                                                      "return": metrics["return"]}})
                recorder.close()
            except BaseException:
                recorder.abort()
                raise
            if screenshot is not None:
                window.screenshot(screenshot)
            summary = {
                "track": race.track.name, "intent": spec.intent, "seed": spec.seed,
                "assistant": assistant.id if assistant is not None else None,
                "method": assistant.method.name if assistant is not None else None,
                "participant": spec.participant, "trial": spec.trial,
                "metrics": metrics, "met_intent": bool(meets_intent(spec.intent, metrics)),
                "read_as_stated": float(np.mean(read_as_stated)) if read_as_stated else None,
            }
            inputs = [track_id] + ([assistant.id] if assistant is not None else [])
            labels = {"track": race.track.name, "intent": spec.intent,
                      "assistant": assistant.id if assistant is not None else None,
                      "participant": spec.participant, "trial": spec.trial}
            with store.create(DRIVE_KIND, inputs=inputs, config=record, seed=spec.seed, labels=labels) as writer:
                writer.add_file("drive.mcap", log_path)
                writer.add_json("drive.json", summary)
                writer.note("wall_s", round(time.monotonic() - started, 3))
            return {"id": writer.artifact.id, **summary}
    finally:
        if own_window:
            window.close()
        env.close()
