"""`paper_values.yaml` parses, has the shape the report reads, and its Table 1 agrees with the
appendix tables it was typed separately from (a check on the typing)."""

from __future__ import annotations

import math

import yaml

from d2a_core.report import paper
from d2a_core.report.paper import PAPER_VALUES

METHODS = {"dreamer", "dreamer-ail", "dream2assist", "dream2assist+a", "dream2assist+a-r"}


def _is_cell(cell) -> bool:
    return (isinstance(cell, list) and len(cell) == 2 and all(isinstance(v, (int, float)) for v in cell)
            and cell[1] >= 0)


def test_the_file_parses_and_every_cell_is_a_mean_and_std():
    values = yaml.safe_load(PAPER_VALUES.read_text(encoding="utf-8"))
    assert values["metrics"] == ["progress_m", "return", "collision", "intervention", "mean_speed_m_s"]
    assert set(values["paper_names"]) == METHODS
    pairs = {"tab:pass_stay": ("pass-stay", ("pass", "stay")), "tab:left_right": ("left-right", ("left", "right"))}
    assert set(values["appendix"]) == set(pairs)
    for label, (pair, intents) in pairs.items():
        table = values["appendix"][label]
        assert table["pair"] == pair
        for track in ("hairpin", "straightaway"):
            assert set(table[track]) == set(intents)
            for intent in intents:
                assert set(table[track][intent]) == METHODS
                for method, row in table[track][intent].items():
                    assert len(row) == 5 and all(_is_cell(c) for c in row), (label, track, intent, method)
    for pair in ("pass-stay", "left-right"):
        for track in ("hairpin", "straightaway"):
            mean, std = values["f1"][pair][track]
            assert 0.9 <= mean <= 1.0 and 0 <= std < 0.01
    assert values["intent_swap"]["recovery_s"] == [4.0, 8.0]


def test_table1_equals_the_appendix_tables():
    values = paper.load()
    table1 = values["table1"]
    assert table1["label"] == "tab:ablations"
    compared = 0
    for track in ("hairpin", "straightaway"):
        for intent, rows in table1[track].items():
            for method, cells in rows.items():
                for metric, cell in zip(table1["metrics"], cells):
                    appendix = paper.change_cell(track, "pass-stay" if intent in ("pass", "stay") else "left-right",
                                                 intent, method, metric)
                    assert appendix is not None
                    # Table 1 prints one std as 31.91 where the appendix has 31.9
                    assert math.isclose(cell[0], appendix["mean"]), (track, intent, method, metric)
                    assert abs(cell[1] - appendix["std"]) <= 0.011, (track, intent, method, metric)
                    compared += 1
    assert compared == 2 * 4 * 3 * 3


def test_lookups():
    assert paper.change_cell("hairpin", "pass-stay", "pass", "dream2assist", "progress_m") == {
        "mean": 71.8, "std": 43.9, "table": "tab:pass_stay"}
    assert paper.change_cell("hairpin", "left-right", "left", "dreamer", "intervention")["mean"] == 0.14
    assert paper.change_cell("hairpin", "pass-stay", "pass", "no-rssm", "progress_m") is None
    assert paper.change_cell("oval", "pass-stay", "pass", "dreamer", "progress_m") is None
    assert paper.f1_cell("straightaway", "pass-stay", "dream2assist")["mean"] == 1.0
    assert paper.f1_cell("straightaway", "pass-stay", "dreamer") is None
    assert paper.swap_cell("hairpin", "pass-stay", "dream2assist")["recovery_s"] == [4.0, 8.0]
    assert paper.paper_name("dream2assist+a-r") == "Dream2Assist+a-r" and paper.paper_name("no-rssm") == "no-rssm"
