"""`d2a reproduce`: the paper's experiment grid as data.

The grid is a list of *cells*, each one invocation of an existing subcommand (`make-track`,
`train-humans`, `train-assistant`, `eval`, `intent-swap`, `report`) with its exact argv, the
cells it depends on and the aliases it yields. Executors (`pipelines.executors`) run each cell as
`python -m d2a_cli <argv> --store STORE --json` in a subprocess, so a cell is the subcommand's
own code path and makes the artifacts that command would make; nothing here trains or evaluates.

Cells, in dependency order:

- `make-track/<track>`: `d2a make-track <track> --preset P --seed 0`, per track;
- `train-humans/<track>/<intent>/seed<H>`: `d2a train-humans --intent I --track T --preset P
  --seed H`, per (track, intent) of the grid's pairs and per H of `humans_seeds` (default 0); the
  first seed's population is the intent's reference (`humans/<track>/<intent>`), the others
  train with `--no-alias` (side populations, `humans/<track>/<intent>/side/<id>`);
- `train-assistant/<track>/<pair>/<method>/seed<k>`: `d2a train-assistant --track T --pair P
  --method M --humans <pop a> --humans <pop b> --preset P --seed k`, k = 0 .. seeds-1, the
  populations given by id (taken from the train-humans cells' results when the cell starts); with
  several humans seeds, `--humans <ref a>,<side a>,...` per intent;
- `eval/<track>/<pair>`: `d2a eval --track T --pair P --method M0 --baseline M1 ... --seed 0 ...
  --seed S-1 --episodes E --eval-seed 0 --envs N`, over every method and seed of the pair;
- `intent-swap/<track>/<pair>`: `d2a intent-swap ...` likewise (`--trials`);
- `report`: `d2a report --track T ... --pair P ...`, after everything.

How seeds and populations map: every assistant seed of a (track, pair) trains with the *same*
populations (by default one per intent, trained with seed 0), as the paper's protocol freezes
one population per intent; the seeds of a grid are assistant training seeds. Several
`humans_seeds` train every assistant on several populations per intent (the first of each is
the reference: its expert and panel are the assistant's, and evaluation uses it). Reasons:
`eval` and `intent-swap` take one population per intent for all seeds they evaluate, and the
report counts an evaluation made with `--humans` as one on *held-out* humans (its alias gets a
`/humans-<ids>` suffix), so evaluation must use the populations behind the
`humans/<track>/<intent>` aliases. The train-assistant cells still pass the populations by id
(`--humans`): the run key hashes the population ids, not the alias, so the assistants are the same
as without `--humans`, and a population alias moved by someone else between two cells cannot
change what an assistant trains with. The train-humans cell re-points `humans/<track>/<intent>`
at its population when the subcommand returned a stored result (a cached `train-humans` does not
re-tag), and the eval and intent-swap cells check, before they start, that the aliases point at
the grid's populations (`Cell.expects`).

`--set` overrides: `key=value` goes to every cell that takes a config (make-track, train-humans,
train-assistant), so they all resolve the same config; `PATTERN:key=value` only to the cells whose
name matches the shell-style PATTERN or whose kind is PATTERN (e.g.
`train-assistant:assistant.env_steps=480`, `train-assistant/*/seed1:assistant.checkpoints=4`).

Torch threads are not passed as `--set humans.torch_threads=K`: that value is part of the
config a run key and an artifact id hash, so the same grid run with another `--jobs` would
train everything again and fork every id. Executors set `OMP_NUM_THREADS` (which torch reads
when `torch_threads` is 0, the default) in each cell's environment instead.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from typing import Any, Sequence, Union

from d2a_core.errors import UsageError
from d2a_core.run_inputs import parse_pair

KINDS = ("make-track", "train-humans", "train-assistant", "eval", "intent-swap", "report")
CONFIG_KINDS = ("make-track", "train-humans", "train-assistant")
"""Cell kinds whose subcommand takes --preset/--config/--set."""
DEVICE_KINDS = ("train-humans", "train-assistant", "eval", "intent-swap")
"""Cell kinds whose work runs on `--device` (and asks Ray for a GPU when that is cuda)."""

PRESET_EVAL = {
    # paired episodes per human (eval), trials per direction (intent-swap), envs stepped together
    "smoke": {"episodes": 1, "trials": 1, "envs": 2},
    "quick": {"episodes": 20, "trials": 10, "envs": 8},
    "paper": {"episodes": 20, "trials": 10, "envs": 8},
}
MAIN_METHOD = "dream2assist"


@dataclass(frozen=True)
class DepId:
    """An argv placeholder: the artifact id that dependency `cell` yielded under `alias` (None: the
    cell's main artifact, e.g. a side population, whose alias holds its own id), filled in when
    the cell starts (dry runs show it as `<id of ALIAS>`)."""

    cell: str
    alias: str | None

    def __str__(self) -> str:
        return f"<id of {self.alias or self.cell}>"


@dataclass(frozen=True)
class DepIds:
    """An argv placeholder: several dependencies' artifact ids joined by commas (`--humans A,B`)."""

    refs: tuple[DepId, ...]

    def __str__(self) -> str:
        return ",".join(str(r) for r in self.refs)


Arg = Union[str, DepId, DepIds]


@dataclass(frozen=True)
class Cell:
    """One subcommand invocation of the grid."""

    name: str
    kind: str
    argv: tuple[Arg, ...]
    """The subcommand and its arguments, without --store, --json and --device."""
    deps: tuple[str, ...]
    """Names of the cells that must have finished first."""
    artifact: str
    """The alias it yields (for eval and intent-swap: the prefix of its per-method-and-seed aliases)."""
    expects: tuple[tuple[str, DepId], ...] = ()
    """Aliases that must point at a dependency's artifact when the cell starts."""
    config: tuple[str, str | None, tuple[str, ...], str | None] | None = None
    """(preset, config file, overrides, intent pair or None) of a config-taking cell, to fingerprint
    the resolved config (an assistant's takes its pair's `pairs:` values)."""

    @property
    def uses_device(self) -> bool:
        return self.kind in DEVICE_KINDS

    def argv_text(self) -> list[str]:
        return [str(a) for a in self.argv]

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "artifact": self.artifact, "argv": self.argv_text(),
                "deps": list(self.deps)}


@dataclass
class GridOptions:
    preset: str = "quick"
    tracks: Sequence[str] = ("straightaway",)
    pairs: Sequence[str] = ("pass-stay",)
    methods: Sequence[str] | None = None
    """None: every implemented method."""
    seeds: int = 1
    humans_seeds: Sequence[int] = (0,)
    """Seeds of each intent's populations; the first is the reference (aliases, evaluation)."""
    overrides: Sequence[str] = ()
    config_file: str | None = None
    episodes: int | None = None
    trials: int | None = None
    envs: int | None = None
    eval_seed: int = 0


def _unique(values: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(values))


def _split_override(text: str) -> tuple[str | None, str]:
    """`PATTERN:key=value` -> (PATTERN, key=value); `key=value` -> (None, key=value)."""
    key = text.split("=", 1)[0]
    if ":" in key:
        scope, rest = text.split(":", 1)
        if not scope or "=" not in rest:
            raise UsageError(f"--set {text!r}: write key=value or PATTERN:key=value")
        return scope, rest
    return None, text


def _applies(scope: str | None, cell_name: str, kind: str) -> bool:
    return scope is None or scope == kind or fnmatch.fnmatchcase(cell_name, scope)


def expand(opts: GridOptions) -> list[Cell]:
    """The grid's cells in dependency order (every cell after the cells it depends on)."""
    from d2a_core.config.loader import available_presets
    from d2a_core.training.methods import get_method, method_names

    if opts.preset not in available_presets():
        raise UsageError(f"unknown preset {opts.preset!r}; choose from {', '.join(available_presets())}")
    if opts.seeds < 1:
        raise UsageError(f"--seeds must be at least 1, got {opts.seeds}")
    humans_seeds = list(opts.humans_seeds)
    if not humans_seeds or len(set(humans_seeds)) != len(humans_seeds):
        raise UsageError(f"--humans-seed: give one or more distinct seeds, got {humans_seeds}")
    tracks = _unique(opts.tracks)
    pairs = _unique(opts.pairs)
    if not tracks or not pairs:
        raise UsageError("a grid needs at least one --track and one --pair")
    intents_of = {pair: parse_pair(pair) for pair in pairs}
    methods = _unique(opts.methods) if opts.methods else method_names(implemented_only=True)
    for name in methods:
        get_method(name)  # unknown or not implemented: a usage error before anything runs
    main = MAIN_METHOD if MAIN_METHOD in methods else methods[0]
    others = [m for m in methods if m != main]
    seeds = list(range(opts.seeds))
    defaults = PRESET_EVAL.get(opts.preset, PRESET_EVAL["quick"])
    episodes = opts.episodes if opts.episodes is not None else defaults["episodes"]
    trials = opts.trials if opts.trials is not None else defaults["trials"]
    envs = opts.envs if opts.envs is not None else defaults["envs"]
    overrides = [_split_override(o) for o in opts.overrides]

    cells: list[Cell] = []

    def add(name: str, kind: str, argv: list[Arg], deps: list[str], artifact: str,
            expects: Sequence[tuple[str, DepId]] = (), pair: str | None = None) -> Cell:
        mine = [o for scope, o in overrides if _applies(scope, name, kind)]
        config = None
        if kind not in CONFIG_KINDS:  # unscoped overrides are for the config-taking cells only
            mine = [o for scope, o in overrides if scope is not None and _applies(scope, name, kind)]
        if kind in CONFIG_KINDS:
            argv = [*argv, "--preset", opts.preset]
            if opts.config_file:
                argv += ["--config", opts.config_file]
            for o in mine:
                argv += ["--set", o]
            config = (opts.preset, opts.config_file, tuple(mine), pair)
        elif mine:
            raise UsageError(f"--set {mine[0]!r} reaches cell {name}, but `d2a {kind}` takes no config; "
                             f"scope it with PATTERN:key=value (e.g. train-assistant:{mine[0]})")
        cell = Cell(name, kind, tuple(argv), tuple(deps), artifact, tuple(expects), config)
        cells.append(cell)
        return cell

    evals: list[str] = []
    for track in tracks:
        track_cell = add(f"make-track/{track}", "make-track", ["make-track", track, "--seed", "0"], [],
                         f"track/{track}")
        humans: dict[str, tuple[str, str]] = {}  # intent -> (reference cell name, alias)
        sides: dict[str, list[DepId]] = {}  # intent -> the side populations' ids
        for intent in _unique([i for pair in pairs for i in intents_of[pair]]):
            alias = f"humans/{track}/{intent}"
            for k, hseed in enumerate(humans_seeds):
                argv: list[Arg] = ["train-humans", "--intent", intent, "--track", track, "--seed", str(hseed)]
                if k == 0:
                    cell = add(f"train-humans/{track}/{intent}/seed{hseed}", "train-humans", argv,
                               [track_cell.name], alias)
                    humans[intent] = (cell.name, alias)
                else:
                    cell = add(f"train-humans/{track}/{intent}/seed{hseed}", "train-humans",
                               [*argv, "--no-alias"], [track_cell.name], f"{alias}/side")
                    sides.setdefault(intent, []).append(DepId(cell.name, None))
        for pair in pairs:
            intents = intents_of[pair]
            pops = [humans[i] for i in intents]
            pop_args: list[Arg] = []
            for intent, (name, alias) in zip(intents, pops):
                refs = (DepId(name, alias), *sides.get(intent, []))
                pop_args += ["--humans", refs[0] if len(refs) == 1 else DepIds(refs)]
            pop_cells = [ref.cell for i in intents for ref in
                         (DepId(humans[i][0], humans[i][1]), *sides.get(i, []))]
            expects = [(alias, DepId(name, alias)) for name, alias in pops]
            assistants = []
            for method in methods:
                for seed in seeds:
                    cell = add(f"train-assistant/{track}/{pair}/{method}/seed{seed}", "train-assistant",
                               ["train-assistant", "--track", track, "--pair", pair, "--method", method,
                                *pop_args, "--seed", str(seed)],
                               pop_cells, f"assistants/{track}/{pair}/{method}/seed{seed}", pair=pair)
                    assistants.append(cell.name)
            which = ["--track", track, "--pair", pair, "--method", main,
                     *(a for m in others for a in ("--baseline", m)), *(a for s in seeds for a in ("--seed", str(s)))]
            deps = [*assistants, *pop_cells]
            evals.append(add(f"eval/{track}/{pair}", "eval",
                             ["eval", *which, "--episodes", str(episodes), "--eval-seed", str(opts.eval_seed),
                              "--envs", str(envs)], deps, f"eval/{track}/{pair}", expects).name)
            evals.append(add(f"intent-swap/{track}/{pair}", "intent-swap",
                             ["intent-swap", *which, "--trials", str(trials), "--eval-seed", str(opts.eval_seed),
                              "--envs", str(envs)], deps, f"intent-swap/{track}/{pair}", expects).name)
    add("report", "report", ["report", *(a for t in tracks for a in ("--track", t)),
                             *(a for p in pairs for a in ("--pair", p))], evals, "report/latest")
    check_order(cells)
    return cells


def check_order(cells: Sequence[Cell]) -> None:
    """Every dependency names an earlier cell; names are unique (a bug otherwise)."""
    seen: set[str] = set()
    for cell in cells:
        if cell.name in seen:
            raise AssertionError(f"grid cell {cell.name} appears twice")
        missing = [d for d in cell.deps if d not in seen]
        if missing:
            raise AssertionError(f"grid cell {cell.name} depends on {missing}, which do not come before it")
        seen.add(cell.name)


def dependents(cells: Sequence[Cell], name: str) -> list[str]:
    """Every cell that depends on `name`, directly or not, in grid order."""
    out: set[str] = {name}
    for cell in cells:
        if any(d in out for d in cell.deps):
            out.add(cell.name)
    return [c.name for c in cells if c.name in out and c.name != name]
