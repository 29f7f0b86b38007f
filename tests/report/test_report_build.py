"""A report built from the synthetic store (tests/report/conftest.py): its cells, lineage and
determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from d2a_core.artifacts import Store
from d2a_core.errors import UsageError
from d2a_core.report import build_report
from d2a_core.report.stats import bootstrap_ci

from report_store import D2A_SEEDS, make_store


@pytest.fixture(scope="module")
def built(synthetic, tmp_path_factory):
    root, ids = synthetic
    out = tmp_path_factory.mktemp("out") / "report"
    return root, ids, build_report(Store(root), out=out), out


def _table(result, table_id):
    kind = table_id.split("/")[0]
    kind = {"change": "change", "f1": "f1", "swap": "intent_swap"}[kind]
    return next(t for t in result["tables"][kind] if t["id"] == table_id)


def _row(table, method):
    return next(r for r in table["rows"] if r["method"] == method)


def test_the_change_table_has_the_hand_computed_cells(built):
    root, ids, result, _ = built
    table = _table(result, "change/straightaway/pass-stay/pass/imperfect")
    assert table["seeds"] == {"dreamer": [0], "dream2assist": [0, 1, 2]}
    assert table["episodes_per_human"] == [2] and table["humans_per_seed"] == [3]
    assert table["preset"] == {"assistants": ["smoke"], "humans": ["smoke, except humans.checkpoints=4"]}
    assert table["paper_table"] == "tab:pass_stay"

    d2a = _row(table, "dream2assist")["cells"]["progress_m"]
    # change of seed s, human n: 10 s + n -> pooled 1,2,3,11,12,13,21,22,23; seed means 2, 12, 22
    assert d2a["mean"] == pytest.approx(12.0)
    assert d2a["std"] == pytest.approx(np.sqrt(606 / 9), abs=1e-6)
    assert d2a["iqm"] == pytest.approx(12.0)  # trim 2 of 9 at each end: mean of 3, 11, 12, 13, 21
    assert d2a["seed_means"] == [2.0, 12.0, 22.0] and d2a["n_seeds"] == 3 and d2a["n_values"] == 9
    assert d2a["ci"] == pytest.approx(list(bootstrap_ci([2.0, 12.0, 22.0])), abs=1e-6)
    assert d2a["ci_text"].startswith("[")
    assert d2a["improved"] and d2a["best"]
    assert d2a["sources"] == sorted(ids["evaluations"][("dream2assist", s)] for s in D2A_SEEDS)
    assert d2a["paper"] == {"mean": 6.0, "std": 9.1, "table": "tab:pass_stay", "improved": True, "best": False}

    dreamer = _row(table, "dreamer")["cells"]
    assert dreamer["progress_m"]["mean"] == -5.0 and dreamer["progress_m"]["ci_text"] == "n/a (1 seed)"
    assert not dreamer["progress_m"]["improved"] and not dreamer["progress_m"]["best"]
    assert dreamer["progress_m"]["sources"] == [ids["evaluations"][("dreamer", 0)]]
    # collisions: lower is better; interventions are never marked (the paper marks neither)
    assert _row(table, "dream2assist")["cells"]["collision"]["improved"]
    assert _row(table, "dream2assist")["cells"]["collision"]["best"]
    assert not any(_row(table, m)["cells"]["intervention"][k] for m in ("dreamer", "dream2assist")
                   for k in ("improved", "best"))
    # the paper's rows without a run of ours
    ail = _row(table, "dreamer-ail")
    assert not ail["ran"] and ail["cells"]["progress_m"]["mean"] is None
    assert ail["cells"]["progress_m"]["paper"]["mean"] == -116.6

    # the intent criterion (not in the paper): seed means 0, 0.1, 0.2; dreamer's evaluation has none
    met = _row(table, "dream2assist")["cells"]["intent_criterion"]
    assert met["mean"] == pytest.approx(0.1) and met["improved"] and met["paper"] is None
    assert _row(table, "dreamer")["cells"]["intent_criterion"]["mean"] is None

    stay = _row(_table(result, "change/straightaway/pass-stay/stay/imperfect"), "dream2assist")["cells"]["progress_m"]
    assert stay["mean"] == pytest.approx(6.0)  # half of pass's
    near = _table(result, "change/straightaway/pass-stay/pass/near_perfect")
    assert [r["method"] for r in near["rows"]] == ["dreamer", "dream2assist"]  # no paper rows for near-perfect
    assert near["paper_table"] is None and _row(near, "dream2assist")["cells"]["progress_m"]["mean"] == -1.0
    assert not _row(near, "dream2assist")["cells"]["intent_criterion"]["improved"]  # -0.5: lost its goal
    # the safety rule: collisions up by 0.1 > 0.05 on the near-perfect humans, down on the imperfect ones
    assert near["unsafe"] == ["dream2assist"] and _row(near, "dream2assist")["cells"]["collision"]["unsafe"]
    assert table["unsafe"] == [] and not _row(table, "dream2assist")["cells"]["collision"]["unsafe"]
    # ... and leaving the track more often breaks it too (stay near-perfect: +0.2 off track, no collision)
    stay_near = _table(result, "change/straightaway/pass-stay/stay/near_perfect")
    cells = _row(stay_near, "dream2assist")["cells"]
    assert stay_near["unsafe"] == ["dream2assist"] and cells["off_track"]["unsafe"] and not cells["collision"]["unsafe"]
    # dreamer's evaluation predates the off-track rate: no value, nothing flagged
    assert _row(stay_near, "dreamer")["cells"]["off_track"]["mean"] is None
    assert _row(table, "dream2assist")["cells"]["off_track"]["improved"]


def test_f1_and_intent_swap_tables(built):
    _, ids, result, _ = built
    f1 = _table(result, "f1/straightaway/pass-stay")
    assert f1["no_intent_estimate"] == ["dreamer"]
    row = _row(f1, "dream2assist")
    assert row["training"]["mean"] == pytest.approx(0.8)  # 0.9, 0.8, 0.7
    assert row["training"]["n_seeds"] == 3 and row["training"]["ci"] is not None
    assert row["heldout"]["mean"] == pytest.approx(0.6) and row["heldout"]["ci_text"] == "n/a (1 seed)"
    assert row["heldout"]["sources"] == [ids["heldout"]]
    assert row["paper"] == {"mean": 1.0, "std": 0.0, "table": "tab:f1-scores"}

    swap = _table(result, "swap/straightaway/pass-stay")
    d2a = _row(swap, "dream2assist")["directions"]["pass-to-stay"]
    assert d2a["mean"] == pytest.approx(2.0) and d2a["seeds_recovered"] == 2 and d2a["ci_text"] == "n/a (2 seeds)"
    assert d2a["recovered_trials"] == 6 and d2a["trials"] == 8
    assert d2a["metrics"]["progress_m"]["mean"] == 5.0 and d2a["metrics"]["progress_m"]["improved"]
    never = _row(swap, "dreamer")["directions"]["stay-to-pass"]
    assert never["mean"] is None and never["seeds_recovered"] == 0 and never["seeds_total"] == 1


def test_lineage_is_exactly_the_artifacts_used(built):
    root, ids, result, _ = built
    store = Store(root)
    expected = {*ids["evaluations"].values(), ids["heldout"], *ids["swaps"].values(), *ids["runs"].values(),
                *ids["assistants"].values(), *ids["populations"].values()}
    art = store.get(result["id"])
    assert art.kind == "report" and set(art.inputs) == expected == set(result["inputs"])
    assert ids["superseded"] not in art.inputs and ids["track"] not in art.inputs  # no alias / not read
    assert store.resolve("report/latest") == result["id"]
    stored = json.loads(store.read_bytes(result["id"], "tables.json"))
    assert stored["tables"] == json.loads(json.dumps(result["tables"]))
    # every figure names its sources, and they are inputs
    for fig in stored["figures"]:
        assert fig["sources"] and set(fig["sources"]) <= expected, fig["name"]
    md = store.read_bytes(result["id"], "report.md").decode()
    assert all(i in md for i in expected)  # the artifact list at the end
    assert ids["evaluations"][("dreamer", 0)][:12] in md and "n/a (1 seed)" in md and "not run" in md
    assert "Intent met" in md and "not recorded" in md  # dreamer's evaluation has no intent criterion
    # the safety rule, broken by dream2assist's near-perfect rows only: marked and said once per table
    assert md.count("Safety rule broken") == 2 and "⚠ unsafe" in md  # pass and stay, near-perfect


def test_all_five_figure_kinds_and_the_files(built):
    _, _, result, out = built
    kinds = {f["kind"] for f in result["figures"]}
    assert kinds == {"change_bars", "learning_curves", "time_traces", "tsne", "swap_accuracy"}
    assert result["skipped_figures"] == {}
    names = {f["name"] for f in result["figures"]}
    assert {"change-straightaway-pass-stay-pass", "curves-humans-straightaway", "tsne-straightaway-pass-stay",
            "curves-assistants-straightaway-pass-stay", "trace-straightaway-pass-stay-pass",
            "trace-straightaway-pass-stay-stay", "swap-straightaway-pass-stay"} <= names
    traces = {f["name"]: f["caption"] for f in result["figures"] if f["kind"] == "time_traces"}
    assert "MCAP log" in traces["trace-straightaway-pass-stay-pass"]  # the pass episode has a log
    assert "steps.npz" in traces["trace-straightaway-pass-stay-stay"]  # the stay one falls back
    for name in names:
        png, svg = (out / "figures" / f"{name}.png").read_bytes(), (out / "figures" / f"{name}.svg").read_bytes()
        assert png.startswith(b"\x89PNG") and b"<svg" in svg
        assert b"Software" not in png and b"<dc:date>" not in svg and b"Matplotlib v" not in svg
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == len(names) and 'class="improved"' in page
    assert (out / "report.md").is_file() and (out / "tables.json").is_file()


def test_same_store_content_gives_the_same_report(built, tmp_path):
    root, _, result, out = built
    # a second build on the same store, and one on a store made again (other creation times)
    assert build_report(Store(root))["id"] == result["id"]
    again = tmp_path / "store"
    make_store(again)
    second = build_report(Store(again), out=tmp_path / "out")
    assert second["id"] == result["id"]
    for name in result["files"]:
        assert (tmp_path / "out" / name).read_bytes() == (out / name).read_bytes(), name


def test_selection_and_errors(built, tmp_path):
    root, _, result, _ = built
    with pytest.raises(UsageError, match="track hairpin .* it has: straightaway"):
        build_report(Store(root), tracks=["hairpin"])
    only = build_report(Store(root), pairs=["pass-stay"], tracks=["straightaway"])
    assert only["id"] != result["id"]  # a different selection is recorded in the report
    assert only["tables"]["change"] == result["tables"]["change"]
    with pytest.raises(UsageError, match="d2a eval"):
        build_report(Store(tmp_path / "empty"))
    assert not (tmp_path / "empty").exists()  # reporting on nothing creates no store
