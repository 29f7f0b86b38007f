"""Filling a population's imperfect span from weight snapshots.

The paper's fictitious co-play population has a checkpoint at every 1 % of training; ours keeps
`humans.checkpoints` evenly spaced ones (10 under `quick`). A driver that learns its intent in
the first few thousand steps (stay on the straightaway learns to follow by 6-8k of 40k) then has
only one to three checkpoints below 75 % of the expert, and the evaluation protocol asks for five
imperfect humans at every 20 % of the expert's performance. So the run also keeps the weights
every `humans.snapshot_every` steps, and after training, while fewer than `humans.fill_imperfect`
checkpoints other than the expert are below `NEAR_PERFECT` (75 %), evaluates one more snapshot
and adds it to the population as a checkpoint.

Which snapshot: the evaluated checkpoints (and the start of training, counted as performance 0)
split the run into intervals; take the interval whose weaker end performs worst (drivers near a
weak checkpoint are likely weak too), on a tie the one whose ends differ most (a learning
transition holds the intermediate drivers the 20 % levels ask for), then the earlier one, and
evaluate the snapshot nearest its middle (so a few evaluations already spread over the interval).

The expert is chosen among the evenly spaced checkpoints before the fill, so filling never
changes it; evaluation happens after training, so it never changes the trained weights either.
"""

from __future__ import annotations

from collections.abc import Sequence

from d2a_core.evaluation.paired import NEAR_PERFECT


def below_near_perfect(performance: Sequence[float], expert: int) -> int:
    """How many checkpoints other than the expert perform below `NEAR_PERFECT`."""
    return sum(1 for k, p in enumerate(performance) if k != expert and p < NEAR_PERFECT)


def next_snapshot(evaluated: Sequence[tuple[int, float]], snapshots: Sequence[int]) -> int | None:
    """The env step of the snapshot to evaluate next (module docstring), or None when no
    snapshot lies strictly between two evaluated points.

    `evaluated`: (env step, performance) of every checkpoint so far; `snapshots`: the env steps of
    the snapshots not yet evaluated."""
    points = sorted({0: 0.0, **{step: perf for step, perf in evaluated}}.items())
    best: tuple[tuple[float, float, int], int] | None = None
    for (a, pa), (b, pb) in zip(points, points[1:]):
        inside = [s for s in snapshots if a < s < b]
        if not inside:
            continue
        middle = min(inside, key=lambda s: (abs(s - (a + b) / 2), s))
        rank = (min(pa, pb), -abs(pa - pb), a)
        if best is None or rank < best[0]:
            best = (rank, middle)
    return None if best is None else best[1]
