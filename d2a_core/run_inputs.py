"""What a run reads from the store before it starts: a track with its opponent replays, the
intent pair, and the populations of each intent. Torch-free, and the simulator is imported only
when a track is loaded, so that every layer above it (training, pipelines, the grid driver, the
CLI) can use it without importing a learner or pybullet."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from d2a_core.artifacts import Store
from d2a_core.errors import NotFoundError, UsageError
from d2a_core.objectives.rewards import INTENTS

if TYPE_CHECKING:
    from d2a_core.sim.race_env import RaceEnv
    from d2a_core.sim.replay import OpponentReplay
    from d2a_core.tracks.track import Track


ENV_SECTIONS = ("env", "reward", "vehicle", "world")
"""The config sections that define the env a run drove in: an artifact's record of these is what
another run must match to drive the same env (evaluation, intent swap, demonstrations, drives)."""


@dataclass
class TrackBundle:
    """A track and its opponent replays, loaded from the store."""

    track_id: str
    track: Track
    replay_ids: list[str]
    replays: list[OpponentReplay]

    def env(self, cfg: Any, intent: str | None = None) -> RaceEnv:
        """A race env on this track with its replays and `cfg`'s env, reward, vehicle and world
        sections (`cfg`: a `Config`, or anything with those attributes)."""
        from d2a_core.sim.race_env import RaceEnv

        return RaceEnv(self.track, self.replays, intent=intent, env_config=cfg.env, reward_config=cfg.reward,
                       vehicle_config=cfg.vehicle, world_config=cfg.world)


def track_of(store: Store, ref: str) -> str:
    """The id of the track an artifact was made on: the `track` artifact in its lineage."""
    seen: set[str] = set()
    stack = [store.resolve(ref)]
    while stack:
        art_id = stack.pop()
        if art_id in seen:
            continue
        seen.add(art_id)
        art = store.get(art_id)
        if art.kind == "track":
            return art_id
        stack.extend(art.inputs)
    raise NotFoundError(f"{ref} was not made on a track in store {store.root}")


def resolve_track(store: Store, ref: str) -> str:
    """A track's id from its id, prefix, alias or bare name (`hairpin` means alias `track/hairpin`)."""
    try:
        track_id = store.resolve(ref)
    except NotFoundError:
        if "/" in ref:
            raise
        try:
            track_id = store.resolve(f"track/{ref}")
        except NotFoundError:
            raise NotFoundError(f"no track {ref!r} in store {store.root}; build it with: d2a make-track {ref}") from None
    return track_id


def load_track_bundle(store: Store, ref: str, dt: float) -> TrackBundle:
    """A track by id, prefix, alias or bare name, with its opponent replays."""
    track_id = resolve_track(store, ref)
    art = store.get(track_id)
    if art.kind != "track":
        raise UsageError(f"{ref} is a {art.kind} artifact, not a track")
    from d2a_core.sim.replay import OpponentReplay
    from d2a_core.tracks.track_file import load_track

    track = load_track(store.path(track_id, "track.npz"))
    replay_ids = opponents_of(store, track_id)
    replays = [OpponentReplay.from_log(store.path(rid, "replay.mcap"), "opponent", dt=dt) for rid in replay_ids]
    return TrackBundle(track_id, track, replay_ids, replays)


def opponents_of(store: Store, track_ref: str) -> list[str]:
    """Ids of the newest complete set of replays recorded on a track, in index order.

    A set is the replays of one make-track run (same config and seed); it is complete when it
    holds every index below the `opponents.count` of that config. An interrupted run leaves an
    incomplete set, which is never used.
    """
    track_id = store.resolve(track_ref)
    sets: dict[str, dict[int, Any]] = {}
    for art in store.list("replay"):
        if art.inputs == [track_id]:
            key = json.dumps([art.config, art.seed], sort_keys=True)
            sets.setdefault(key, {})[art.labels.get("index")] = art
    complete, partial = [], []
    for members in sets.values():
        first = next(iter(members.values()))
        count = (first.config or {}).get("opponents", {}).get("count") if isinstance(first.config, dict) else None
        if isinstance(count, int) and count > 0 and set(members) == set(range(count)):
            complete.append(members)
        else:
            partial.append((len(members), count))
    if not complete:
        if partial:
            found, expected = max(partial, key=lambda p: p[0])
            raise UsageError(f"track {track_ref} has no complete set of opponent replays in store {store.root} "
                             f"(found {found} of {expected}: make-track was interrupted); run d2a make-track again")
        raise UsageError(f"track {track_ref} has no opponent replays in store {store.root}; run d2a make-track")
    newest = max(complete, key=lambda m: max((a.created, a.id) for a in m.values()))
    return [newest[i].id for i in sorted(newest)]


PAIRS = ("pass-stay", "left-right")
"""The paper's pairs; any two distinct intents written `a-b` are accepted."""

def parse_pair(pair: str) -> tuple[str, str]:
    """`pass-stay` -> ("pass", "stay"); a UsageError names the valid forms."""
    parts = tuple(pair.split("-"))
    if len(parts) != 2 or parts[0] == parts[1] or not all(p in INTENTS for p in parts):
        raise UsageError(f"pair {pair!r}: write two distinct intents as 'a-b' (the paper's: {', '.join(PAIRS)}; "
                         f"intents: {', '.join(INTENTS)})")
    return parts  # type: ignore[return-value]


def load_populations(store: Store, bundle: TrackBundle, intents: Sequence[str],
                     refs: Sequence[str] | None) -> list[tuple[str, dict[str, Any]]]:
    """(id, population.json) per intent of the pair, from `refs` or the default aliases."""
    if refs is not None and len(refs) != len(intents):
        raise UsageError(f"--humans takes one population per intent of the pair ({len(intents)}), got {len(refs)}")
    out = []
    for k, intent in enumerate(intents):
        ref = refs[k] if refs is not None else f"humans/{bundle.track.name}/{intent}"
        if "," in ref:
            raise UsageError(f"--humans {ref}: one population per intent here (only train-assistant trains with several)")
        out.append(_load_population(store, bundle, intent, ref))
    return out


def load_population_groups(store: Store, bundle: TrackBundle, intents: Sequence[str],
                           refs: Sequence[str] | None) -> list[list[tuple[str, dict[str, Any]]]]:
    """The populations of each intent of the pair: `refs[k]` is one ref or a comma-separated list
    (fictitious co-play over several training seeds, for partners more diverse than one run's
    checkpoints). The first of each list is the intent's reference population: its expert
    filters the reward and its humans form the evaluation panel; the others add drivers."""
    if refs is not None and len(refs) != len(intents):
        raise UsageError(f"--humans takes one population per intent of the pair ({len(intents)}), got {len(refs)} "
                         "(several populations of one intent go in one entry: --humans A,B)")
    groups = []
    for k, intent in enumerate(intents):
        names = [r.strip() for r in refs[k].split(",")] if refs is not None else [f"humans/{bundle.track.name}/{intent}"]
        if not all(names):
            raise UsageError(f"--humans {refs[k]!r}: an empty population ref in the list")  # type: ignore[index]
        group = [_load_population(store, bundle, intent, name) for name in names]
        ids = [pid for pid, _ in group]
        if len(set(ids)) < len(ids):
            raise UsageError(f"--humans {refs[k]!r} lists one {intent} population twice")  # type: ignore[index]
        groups.append(group)
    return groups


def _load_population(store: Store, bundle: TrackBundle, intent: str, ref: str) -> tuple[str, dict[str, Any]]:
    try:
        art = store.get(ref)
    except NotFoundError:
        raise NotFoundError(
            f"no population {ref!r} in store {store.root}; make it with: "
            f"d2a train-humans --intent {intent} --track {bundle.track.name}") from None
    if art.kind != "population":
        raise UsageError(f"{ref} is a {art.kind} artifact, not a population")
    pop = store.read_json(art.id, "population.json")
    if pop["intent"] != intent:
        raise UsageError(f"population {ref} is of intent {pop['intent']!r}, not {intent!r} "
                         f"(--humans lists the pair's populations in order)")
    if pop["track_id"] != bundle.track_id:
        raise UsageError(f"population {ref} was trained on track {pop['track_id'][:12]}, not "
                         f"{bundle.track.name} ({bundle.track_id[:12]})")
    return art.id, pop
