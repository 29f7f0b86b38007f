"""`d2a report` on the command line: the JSON it prints, --out, and the errors that name what to run."""

from __future__ import annotations

from d2a_core.artifacts import Store


def test_an_empty_store_exits_2_naming_the_commands(cli, tmp_path):
    res = cli("report", "--json", store=tmp_path / "empty")
    assert res.code == 2, res.stderr
    message = res.json["error"]["message"]
    assert res.json["error"]["type"] == "UsageError"
    for command in ("d2a eval", "d2a intent-swap", "d2a train-assistant", "d2a train-humans"):
        assert command in message and command in res.stderr


def test_report_prints_its_id_files_and_tables(cli, synthetic, tmp_path):
    root, ids = synthetic
    out = tmp_path / "copy"
    res = cli("report", "--track", "straightaway", "--pair", "pass-stay", "--out", str(out), "--json", store=root)
    assert res.code == 0, res.stderr
    data = res.json
    assert set(data) >= {"id", "files", "tables"}
    assert Store(root).resolve("report/latest") == data["id"]
    assert {"report.md", "report.html", "tables.json"} <= set(data["files"])
    assert sum(f.endswith(".png") for f in data["files"]) == sum(f.endswith(".svg") for f in data["files"]) >= 5
    assert all((out / name).is_file() for name in data["files"])
    assert [t["id"] for t in data["tables"]["f1"]] == ["f1/straightaway/pass-stay"]
    bad = cli("report", "--track", "hairpin", store=root)
    assert bad.code == 2 and "it has: straightaway" in bad.stderr
