"""Live training curves: every training command writes its curve while it trains, as JSONL and
as TensorBoard event files that the real `tensorboard` package reads."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from d2a_core.artifacts import Store
from d2a_core.training.tensorboard_events import ScalarEventWriter, crc32c
from d2a_test_helpers import kill_after_state_saved

event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")


def _scalars(folder: Path) -> dict[str, list[tuple[int, float]]]:
    acc = event_accumulator.EventAccumulator(str(folder), size_guidance={event_accumulator.SCALARS: 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _numbers(row: dict) -> dict[str, float]:
    return {k: float(v) for k, v in row.items() if k != "env_step" and isinstance(v, (int, float))
            and not isinstance(v, bool) and math.isfinite(v)}


def _check_folder_matches_artifact(folder: Path, curve_bytes: bytes) -> None:
    assert (folder / "curve.jsonl").read_bytes() == curve_bytes
    rows = [json.loads(line) for line in curve_bytes.decode().splitlines()]
    assert len(rows) >= 2
    scalars = _scalars(folder)
    tags = set().union(*(_numbers(r) for r in rows))
    assert set(scalars) == tags
    for tag in tags:
        expected = [(r["env_step"], _numbers(r)[tag]) for r in rows if tag in _numbers(r)]
        got = scalars[tag]
        assert [s for s, _ in got] == [s for s, _ in expected], tag
        assert [v for _, v in got] == pytest.approx([v for _, v in expected], rel=1e-6, abs=1e-6), tag


def test_crc32c_known_value():
    assert crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value


def test_rows_are_readable_before_the_writer_closes(tmp_path):
    writer = ScalarEventWriter(tmp_path / "run")
    writer.add_scalars(10, {"loss/model": 2.5, "note": "text", "flag": True, "gap": float("nan")})
    writer.add_scalars(20, {"loss/model": 1.5})
    assert _scalars(tmp_path / "run") == {"loss/model": [(10, 2.5), (20, 1.5)]}
    writer.close()


def test_population_curves_are_live_logs_of_the_stored_curve(pair_store_template):
    store = Store(pair_store_template)
    for population in store.list("population"):
        intent = population.labels["intent"]
        folders = list((pair_store_template / "logs" / "humans" / "straightaway" / intent).iterdir())
        key = population.labels["run_key"]
        folder = next(f for f in folders if f.name.endswith(key[:12]))
        _check_folder_matches_artifact(folder, store.path(population.id, "curve.jsonl").read_bytes())


def test_assistant_curves_are_live_logs_of_the_stored_curve(trained_assistants):
    store_dir, _ = trained_assistants
    store = Store(store_dir)
    runs = store.list("assistant-run")
    assert runs
    for run in runs:
        labels = run.labels
        parent = store_dir / "logs" / "assistants" / "straightaway" / labels["pair"] / labels["method"]
        folder = next(f for f in parent.iterdir() if f.name.endswith(labels["run_key"][:12]))
        _check_folder_matches_artifact(folder, store.path(run.id, "curve.jsonl").read_bytes())


def test_a_resumed_run_rewrites_its_live_curve_from_the_saved_rows(tmp_path, cli):
    store = tmp_path / "store"
    assert cli("make-track", "straightaway", "--preset", "smoke", "--json", store=store).code == 0
    args = ["train-humans", "--intent", "stay", "--track", "straightaway", "--preset", "smoke",
            "--set", "humans.checkpoints=4", "--set", "humans.log_every=20", "--json"]
    kill_after_state_saved(args, store)
    res = cli(*args, store=store)
    assert res.code == 0, res.stderr
    assert res.json["populations"][0]["resumed_from_env_step"] is not None
    population = Store(store).get(res.json["populations"][0]["id"])
    (folder,) = (store / "logs" / "humans" / "straightaway" / "stay").iterdir()
    _check_folder_matches_artifact(folder, Store(store).path(population.id, "curve.jsonl").read_bytes())
