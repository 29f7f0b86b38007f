"""Read a centreline CSV in the common racing-line format.

Each data line is `x_m, y_m, w_tr_right_m, w_tr_left_m` with an optional fifth column `z_m`:
the centreline point and the distances from it to the right and left track edges. Blank lines and
lines starting with `#` are skipped (a `# x_m, y_m, ...` header is the usual first line); a header
line without `#` is accepted too. The file is one lap: when its last point comes back near its
first (see `CentrelineCsvConfig.closing_gap_factor`) it is treated as closed, otherwise as an open
section.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from d2a_core.errors import SpecError
from d2a_core.tracks.config import CentrelineCsvConfig
from d2a_core.tracks.limits import MAX_COORD_M

COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m", "z_m")
# Two consecutive points closer than this are a duplicate, which has no direction.
_MIN_STEP_M = 1e-6


@dataclass
class RawCentreline:
    """Points as read from the file, with the line number each came from."""

    x: np.ndarray
    y: np.ndarray
    w_right: np.ndarray
    w_left: np.ndarray
    z: np.ndarray | None
    lines: np.ndarray
    closed: bool


def _header_names(fields: list[str]) -> list[str] | None:
    """Lower-cased column names when the line's first field names `x_m`, else None."""
    names = [f.strip().lstrip("#").strip().lower() for f in fields]
    return names if names and names[0] == "x_m" else None


def _check_header(names: list[str], source: str, line: int) -> int:
    if names not in (list(COLUMNS[:4]), list(COLUMNS)):
        raise SpecError(
            f"{source}:{line}: header must be '{', '.join(COLUMNS[:4])}' with optional ', z_m' (got {', '.join(names)})"
        )
    return len(names)


def read_centreline_csv(path: str | Path, config: CentrelineCsvConfig | None = None) -> RawCentreline:
    """Parse and check a racing-line CSV.

    Raises:
        SpecError: naming the file and line for an unreadable file, a bad header, a wrong column
            count, a non-numeric or non-finite value, a non-positive width, a repeated point, or
            too few points.
    """
    config = config or CentrelineCsvConfig()
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SpecError(f"{source}: cannot read the centreline file ({error})") from error
    n_columns: int | None = None
    rows: list[list[float]] = []
    lines: list[int] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if not stripped:
            continue
        fields = [f.strip() for f in stripped.split(",")]
        header = _header_names(fields) if not rows and n_columns is None else None
        if header is not None:
            n_columns = _check_header(header, source, number)
            continue
        if stripped.startswith("#"):
            continue
        if n_columns is None:
            n_columns = len(fields)
            if n_columns not in (4, 5):
                raise SpecError(
                    f"{source}:{number}: expected 4 or 5 comma-separated columns "
                    f"({', '.join(COLUMNS)}), got {len(fields)}"
                )
        if len(fields) != n_columns:
            raise SpecError(f"{source}:{number}: expected {n_columns} columns, got {len(fields)}")
        values = []
        for column, field in enumerate(fields):
            try:
                value = float(field)
            except ValueError:
                raise SpecError(f"{source}:{number}: {COLUMNS[column]}: {field!r} is not a number") from None
            if not math.isfinite(value):
                raise SpecError(f"{source}:{number}: {COLUMNS[column]}: must be finite (got {field})")
            if abs(value) > MAX_COORD_M:  # 1e300 would overflow the arc-length sums
                raise SpecError(f"{source}:{number}: {COLUMNS[column]}: must be within +-{MAX_COORD_M:g} m (got {field})")
            if column in (2, 3) and value <= 0:
                raise SpecError(f"{source}:{number}: {COLUMNS[column]}: must be > 0 (got {field})")
            values.append(value)
        if rows and math.hypot(values[0] - rows[-1][0], values[1] - rows[-1][1]) < _MIN_STEP_M:
            raise SpecError(f"{source}:{number}: repeats the previous point ({fields[0]}, {fields[1]})")
        rows.append(values)
        lines.append(number)
    if len(rows) < config.min_points:
        raise SpecError(f"{source}: only {len(rows)} points, at least {config.min_points} are needed")
    data = np.array(rows)
    line_numbers = np.array(lines)
    steps = np.hypot(np.diff(data[:, 0]), np.diff(data[:, 1]))
    gap = math.hypot(data[-1, 0] - data[0, 0], data[-1, 1] - data[0, 1])
    closed = gap <= config.closing_gap_factor * float(np.median(steps))
    if closed and gap < _MIN_STEP_M:
        data, line_numbers = data[:-1], line_numbers[:-1]  # the lap repeats its first point at the end
    return RawCentreline(
        x=data[:, 0],
        y=data[:, 1],
        w_right=data[:, 2],
        w_left=data[:, 3],
        z=data[:, 4] if data.shape[1] == 5 else None,
        lines=line_numbers,
        closed=closed,
    )
