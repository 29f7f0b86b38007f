"""Which weight snapshot fills a population's imperfect span next (`training.imperfect_fill`)."""

from __future__ import annotations

from d2a_core.training.imperfect_fill import below_near_perfect, next_snapshot


def test_below_near_perfect_leaves_the_expert_out():
    assert below_near_perfect([0.0, 0.74, 0.75, 1.0, 0.2], expert=3) == 3
    assert below_near_perfect([0.2, 1.0], expert=0) == 0


def test_the_learning_transition_is_split_first():
    # stay on the straightaway: the weakest checkpoint (performance 0 by definition) at 4k,
    # near-perfect from 8k on; the start of training counts as 0 too
    evaluated = [(4000, 0.0), (8000, 1.0), (12000, 1.0)]
    snapshots = [1000, 2000, 3000, 5000, 6000, 7000, 9000, 10000, 11000]
    # weaker end 0 for 0-4k and 4k-8k; 4k-8k spans the wider gap
    assert next_snapshot(evaluated, snapshots) == 6000
    # 6k at 0.4: 4k-6k (0 to 0.4) now beats 0-4k (0 to 0) and 6k-8k (weaker end 0.4)
    snapshots.remove(6000)
    assert next_snapshot([*evaluated, (6000, 0.4)], snapshots) == 5000
    # a start interval is taken when nothing else has a weaker end
    assert next_snapshot([(4000, 0.3), (8000, 1.0)], snapshots) == 2000


def test_ties_go_to_the_wider_gap_then_the_earlier_interval():
    evaluated = [(10, 0.5), (20, 0.5), (30, 0.9), (40, 0.5)]
    # (0, 0.0)-(10, 0.5) has the weakest end
    assert next_snapshot(evaluated, [5, 15, 25, 35]) == 5
    # among the rest, weaker ends 0.5 everywhere: 20-30 and 30-40 differ by 0.4, 10-20 by 0; earlier first
    assert next_snapshot(evaluated, [15, 25, 35]) == 25
    assert next_snapshot(evaluated, [15, 35]) == 35


def test_the_snapshot_nearest_the_middle_and_none_when_nothing_lies_between():
    assert next_snapshot([(100, 0.0)], [10, 40, 60, 90]) == 40
    assert next_snapshot([(100, 0.0)], []) is None
    assert next_snapshot([(100, 0.0), (200, 1.0)], [100, 200, 300]) is None
