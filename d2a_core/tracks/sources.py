"""One entry point for every track source: a spec YAML, a centreline CSV, a saved track file, or
the name of a shipped spec (`straightaway` -> `tracks/straightaway.yaml`)."""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from pathlib import Path

from d2a_core.errors import NotFoundError, SpecError, UsageError
from d2a_core.tracks.centreline_section import load_centreline_csv
from d2a_core.tracks.compile import compile_spec
from d2a_core.tracks.config import TracksConfig
from d2a_core.tracks.spec_loading import load_spec
from d2a_core.tracks.track import Track
from d2a_core.tracks.track_file import load_track

SPEC_SUFFIXES = (".yaml", ".yml")
CSV_SUFFIXES = (".csv",)
TRACK_SUFFIXES = (".npz",)


def _shipped_tracks_dir() -> Path:
    """The shipped specs: the repository's `tracks/`, installed as the package `d2a_tracks`
    (a wheel carries it; an editable install maps it to the checkout)."""
    try:
        import d2a_tracks
    except ImportError:  # a bare source tree on sys.path without installing
        return Path(__file__).resolve().parents[2] / "tracks"
    return Path(d2a_tracks.__file__).resolve().parent


SHIPPED_TRACKS_DIR = _shipped_tracks_dir()
# a track name becomes part of the alias track/<name>: no leading '.', '-' (reads as an option) or '..'
_NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass
class TrackSource:
    """A track together with the file it came from.

    Attributes:
        track: the compiled (or loaded) track.
        path: the source file.
        suffix: its kind, `.yaml`, `.csv` or `.npz` (`.yml` is reported as `.yaml`).
        raw: the source file's bytes, to store beside the compiled track.
        description: one line saying what was built, e.g. `oval.csv [100 m + 500 m]`.
    """

    track: Track
    path: Path
    suffix: str
    raw: bytes
    description: str


def _shipped_names() -> list[str]:
    dirs = [Path.cwd() / "tracks", SHIPPED_TRACKS_DIR]
    return sorted({p.stem for d in dirs if d.is_dir() for p in d.glob("*.yaml")})


def resolve_track_path(source: str | Path) -> Path:
    """The file behind `source`: an existing path, or a bare name of a spec in `tracks/` (looked up
    in the working directory first, then beside the package).

    Raises:
        NotFoundError: a bare name that matches no shipped spec (the message lists close matches).
    """
    path = Path(source)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    for directory in (Path.cwd() / "tracks", SHIPPED_TRACKS_DIR):
        for suffix in SPEC_SUFFIXES:
            candidate = directory / f"{source}{suffix}"
            if candidate.is_file():
                return candidate
    known = _shipped_names()
    close = difflib.get_close_matches(str(source), known, n=3)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    raise NotFoundError(
        f"track {str(source)!r} is neither a file nor a spec in tracks/ (known: {', '.join(known) or 'none'}){hint}"
    )


def load_track_source(
    source: str | Path,
    start_m: float | None = None,
    length_m: float | None = None,
    name: str | None = None,
    config: TracksConfig | None = None,
) -> TrackSource:
    """Build (or load) the track in `source`, chosen by its suffix.

    `.yaml`/`.yml` (or a bare shipped name): a track spec, compiled. `.csv`: a racing-line
    centreline, optionally cut to `start_m .. start_m + length_m` (metres along the file's points,
    wrapping around a closed lap). `.npz`: a track saved with `Track.save`. `name` renames the track.

    Raises:
        SpecError: the file is invalid (message names the file and the field or line).
        UsageError: an unknown suffix, a bad `name`, or `start_m`/`length_m` for a non-CSV source.
        NotFoundError: a bare name that is no shipped spec.
    """
    config = config or TracksConfig()
    path = resolve_track_path(source)
    suffix = path.suffix.lower()
    if suffix not in CSV_SUFFIXES and (start_m is not None or length_m is not None):
        raise UsageError(f"{path}: --start and --length apply only to centreline CSV files")
    if name is not None and not _NAME_PATTERN.match(name):
        raise UsageError(f"--name {name!r}: a track name starts with a letter or digit and may only contain "
                         "letters, digits, '_', '.' and '-'")
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise SpecError(f"{path}: cannot read the track source ({error})") from error
    if suffix in SPEC_SUFFIXES:
        track = compile_spec(load_spec(path), path, config.geometry, config.frenet)
        suffix, description = ".yaml", path.name
    elif suffix in CSV_SUFFIXES:
        track = load_centreline_csv(path, start_m, length_m, config.csv, frenet_config=config.frenet)
        description = f"{path.name} [{track.source['start_m']:g} m + {track.length:.3f} m]"
    elif suffix in TRACK_SUFFIXES:
        track = load_track(path, config.frenet)
        description = path.name
    else:
        known = ", ".join(SPEC_SUFFIXES + CSV_SUFFIXES + TRACK_SUFFIXES)
        raise UsageError(f"{path}: unknown track source type {suffix or '(no suffix)'!r}; expected one of {known}")
    if name is not None:
        track.name = name
    return TrackSource(track=track, path=path, suffix=suffix, raw=raw, description=description)


def build_track(
    source: str | Path,
    start_m: float | None = None,
    length_m: float | None = None,
    config: TracksConfig | None = None,
) -> Track:
    """The `Track` of `load_track_source(source, start_m, length_m, config=config)`."""
    return load_track_source(source, start_m, length_m, config=config).track
