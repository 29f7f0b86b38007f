"""What the per-human analyses of stored `d2a eval` results share: their command line
(`STORE EVAL_ID... [--intent I]`) and the walk over one intent's humans of each evaluation.
Used by passing_side.py and pass_approach.py."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from typing import Any

from d2a_core.artifacts import Store


def parse_args(description: str, argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("store")
    parser.add_argument("evals", nargs="+", help="`evaluation` artifacts (ids of `d2a eval --json`) or aliases")
    parser.add_argument("--intent", default="pass", help="the humans of this intent only")
    return parser.parse_args(argv)


def humans_of(store: Store, refs: list[str], intent: str) -> Iterator[tuple[str, dict[str, Any], int, dict[str, Any]]]:
    """(evaluation id, its stored eval.json, the human's index, the human) for every human of
    `intent` in each evaluation, in stored order."""
    for ref in refs:
        eval_id = store.resolve(ref)
        stored = store.read_json(eval_id, "eval.json")
        for index, human in enumerate(stored["result"]["humans"]):
            if human["intent"] == intent:
                yield eval_id, stored, index, human
