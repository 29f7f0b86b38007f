"""`d2a render`: an episode of a stored driver or assistant, or a stored episode log, as a video.

What REF names decides what is drawn (`report.episode_video` draws it):

- a human checkpoint (or a population: its expert): the driver alone, one episode;
- an assistant: a driver of its pair unassisted and assisted on the same env seed, side by
  side, with the assistant's intent estimate; the driver is `human` or, by default, the
  imperfect checkpoint of the pair's first intent whose performance is nearest 50 % of the
  expert's (someone the assistant has something to do for);
- an evaluation: one of its episode logs (`episode`, a file name of the artifact; default its
  first assisted episode) beside the unassisted episode of the same human and seed;
- a path to an `.mcap` episode log: that episode, on the track its log names (from the store).

Episodes are driven by the evaluator's own engine (`pipelines.evaluate.run_specs`), so they are
the episodes `d2a eval` would drive with one env.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from d2a_core.artifacts import Store
from d2a_core.errors import NotFoundError, UsageError

ENV_SEED_BASE = 70_000_003  # render's env seeds: ENV_SEED_BASE + seed, apart from training and evaluation


def _default_human(store: Store, assistant) -> str:
    track, first = assistant.artifact.labels["track"], assistant.intents[0]
    population = store.read_json(f"humans/{track}/{first}", "population.json")
    imperfect = [c for c in population["checkpoints"] if c["id"] != population["expert"]
                 and c.get("performance") is not None and c["performance"] < 0.75]
    if not imperfect:
        return population["expert"]
    return min(imperfect, key=lambda c: abs(c["performance"] - 0.5))["id"]


def _drive(assistant, driver, seed: int, log_dir: Path, name: str):
    """The driver's episode on env seed `seed`, assisted when `assistant` is given: its log."""
    from d2a_core.pipelines.evaluate import run_specs
    from d2a_core.sim.episode_log import read_episode
    from d2a_core.training.shared_rollout import EpisodeSpec

    intents = assistant.intents if assistant is not None else (driver.intent,)
    label = intents.index(driver.intent) if driver.intent in intents else 0
    maker = assistant.make_env if assistant is not None else driver.make_env
    run_specs([EpisodeSpec(seed=seed, human=0, label=label)], [driver._agent], intents, maker, 1, log_dir / name,
              assistant._agent if assistant is not None else None, {"renderer": "d2a render"},
              partner_window=assistant.partner_window if assistant is not None else 1)
    (log,) = sorted((log_dir / name).glob("*.mcap"))
    return read_episode(log)


def _track(store: Store, name: str | None, lineage_of: str | None = None):
    """The track geometry an episode was driven on: from an artifact's lineage, or by name."""
    from d2a_core.run_inputs import load_track_bundle, track_of

    if lineage_of is not None:
        name = track_of(store, lineage_of)
    if not name:
        raise UsageError("the episode log names no track; render it from a store that holds its track")
    return load_track_bundle(store, name, 0.1).track


def render(store: Store, ref: str, out: Path, human: str | None = None, seed: int = 0, episode: str | None = None,
           fps: float = 10.0, device: str = "cpu") -> dict[str, Any]:
    """Render REF (see the module docstring) to `out` (.gif or .mp4)."""
    from d2a_core import api
    from d2a_core.report.episode_video import frames, write_video
    from d2a_core.sim.episode_log import read_episode

    if out.suffix.lower() not in (".gif", ".mp4"):
        raise UsageError(f"--out {out}: the video must end in .gif or .mp4")
    if out.is_dir():
        raise UsageError(f"--out {out} is a directory")
    path = Path(ref)
    with store.lease(), store.scratch_dir("render") as scratch:
        scratch = Path(scratch)
        what: dict[str, Any] = {}
        if path.suffix == ".mcap" and path.is_file():
            log = read_episode(path)
            panels = [(path.name, log)]
            track = _track(store, log.track_name)
            what = {"log": str(path)}
        else:
            try:
                art = store.get(ref)
            except NotFoundError:
                raise NotFoundError(f"{ref} is neither an episode log (.mcap file) nor an artifact in store "
                                    f"{store.root}") from None
            env_seed = ENV_SEED_BASE + seed
            if art.kind in ("human", "population"):
                driver = api.load(art.id, store, device)
                panels = [(f"{driver.intent} driver {driver.id[:8]} alone", _drive(None, driver, env_seed, scratch,
                                                                                     "alone"))]
                track = _track(store, None, driver.id)
                what = {"human": driver.id, "env_seed": env_seed}
            elif art.kind == "assistant":
                assistant = api.load(art.id, store, device)
                driver = api.load(human or _default_human(store, assistant), store, device)
                if not isinstance(driver, api.Driver):
                    raise UsageError(f"--human {human} is not a human checkpoint or population")
                panels = [(f"{driver.intent} driver {driver.id[:8]} alone",
                           _drive(None, driver, env_seed, scratch, "alone")),
                          (f"with {assistant.method.name} {assistant.id[:8]}",
                           _drive(assistant, api.load(driver.id, store, device), env_seed, scratch, "assisted"))]
                track = _track(store, None, assistant.id)
                what = {"assistant": assistant.id, "human": driver.id, "env_seed": env_seed}
            elif art.kind == "evaluation":
                logs = sorted(n for n in art.files if n.endswith(".mcap"))
                if not logs:
                    raise UsageError(f"evaluation {art.id[:12]} keeps no episode logs")
                name = episode or next((n for n in logs if "/assisted/" in n), logs[0])
                if name not in art.files:
                    raise NotFoundError(f"evaluation {art.id[:12]} has no episode {name!r}; it has e.g. "
                                        + ", ".join(logs[:4]))
                twin = name.replace("/assisted/", "/unassisted/")
                chosen = read_episode(store.path(art.id, name))
                driver = f"{chosen.metadata.get('intent', '')} driver".strip()
                panels = []
                if twin != name and twin in art.files:
                    panels.append((f"{driver} alone", read_episode(store.path(art.id, twin))))
                method = art.labels.get("method", "the assistant")
                panels.append((f"{driver} with {method}" if "/assisted/" in name else Path(name).stem, chosen))
                track = _track(store, None, art.id)
                what = {"evaluation": art.id, "episode": name}
            else:
                raise UsageError(f"{ref} is a {art.kind} artifact; render takes a human, a population, an "
                                 "assistant, an evaluation or an .mcap episode log")
        count = write_video(frames(panels, track), out, fps)
    return {"out": str(out), "frames": count, "fps": fps, "panels": [title for title, _ in panels], **what}
