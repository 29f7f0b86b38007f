"""Run keys and artifact ids hash the config record: retiring a setting, adding one at its
neutral value or regrouping keys must leave every preset's record as stored artifacts hold it.
`data/config_records_before_retirement.json` was written by d2a before the replay and update
experiments were retired (its smoke record has since gained the `dreamer_ail` section that the
smoke preset sets: smoke's artifacts are never kept, quick's and paper's records are unchanged)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from d2a_core.config.loader import resolve_config
from d2a_core.config.schema import Config

STORED = json.loads((Path(__file__).parent / "data" / "config_records_before_retirement.json").read_text())

# Deliberate changes of a preset's behaviour since those records: new runs get new keys, while the
# stored artifacts keep theirs (their records still validate, below).
CHANGED_SINCE = {"quick": {"assistant": {"exact_intervention": True}}}


def _merged(record: dict, changes: dict) -> dict:
    out = dict(record)
    for key, value in changes.items():
        out[key] = _merged(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


@pytest.mark.parametrize("preset", sorted(STORED))
def test_every_presets_record_is_what_stored_runs_hold(preset):
    assert resolve_config(Config, preset).record() == _merged(STORED[preset], CHANGED_SINCE.get(preset, {}))


@pytest.mark.parametrize("preset", sorted(STORED))
def test_a_stored_record_validates(preset):
    """What a manifest holds validates again (as `d2a eval` and the report do with stored configs)."""
    assert Config.model_validate(STORED[preset]).model_dump(mode="json", context={"record": True}) == STORED[preset]
