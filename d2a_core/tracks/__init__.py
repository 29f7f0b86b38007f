"""Tracks: specs (YAML), racing-line CSV sections, the compiled `Track` and its Frenet coordinates.

Typical use:

    from d2a_core.tracks import build_track
    track = build_track("hairpin")     # a shipped name, a .yaml spec, a .csv (start_m/length_m) or a .npz
    s, e = track.to_frenet(x, y, s_hint=previous_s)
    x, y, z = track.from_frenet(s, e)
    save_track(track, "hairpin.npz")   # load_track("hairpin.npz") reads it back
"""

from d2a_core.tracks.centreline_csv import RawCentreline, read_centreline_csv
from d2a_core.tracks.centreline_section import load_centreline_csv
from d2a_core.tracks.compile import compile_spec
from d2a_core.tracks.config import CentrelineCsvConfig, FrenetSearchConfig, TrackGeometryConfig, TracksConfig
from d2a_core.tracks.overlap import Crossing, find_barrier_crossing, find_road_overlap
from d2a_core.tracks.sources import TrackSource, build_track, load_track_source, resolve_track_path
from d2a_core.tracks.spec import TrackSpec
from d2a_core.tracks.spec_loading import load_spec, validate_spec_data
from d2a_core.tracks.track import Barrier, GridSlot, StartGrid, Track, heading_wrap
from d2a_core.tracks.track_file import TRACK_FORMAT, TRACK_FORMAT_VERSION, load_track, save_track

__all__ = [
    "TRACK_FORMAT",
    "TRACK_FORMAT_VERSION",
    "Barrier",
    "CentrelineCsvConfig",
    "Crossing",
    "FrenetSearchConfig",
    "GridSlot",
    "RawCentreline",
    "StartGrid",
    "Track",
    "TrackGeometryConfig",
    "TrackSource",
    "TrackSpec",
    "TracksConfig",
    "build_track",
    "compile_spec",
    "find_barrier_crossing",
    "find_road_overlap",
    "heading_wrap",
    "load_centreline_csv",
    "load_spec",
    "load_track",
    "load_track_source",
    "read_centreline_csv",
    "resolve_track_path",
    "save_track",
    "validate_spec_data",
]
