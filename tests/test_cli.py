"""The CLI frame: help, version, usage errors."""

from __future__ import annotations

import re


def test_help_lists_subcommands_and_global_options(cli):
    res = cli("--help")
    assert res.code == 0
    for word in ("artifacts", "config", "--store", "--json", "--seed", "--device", "--version"):
        assert word in res.stdout


def test_version(cli):
    res = cli("--version")
    assert res.code == 0 and re.match(r"^d2a \d+\.\d+\.\d+", res.stdout)


def test_usage_errors_exit_2(cli):
    assert cli("no-such-command").code == 2
    assert cli("artifacts", "ls", "--no-such-option").code == 2
    res = cli("artifacts", "show", "--json")   # missing argument
    assert res.code == 2 and "error" in res.json
