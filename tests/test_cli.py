"""The CLI frame: help, version, usage errors."""

from __future__ import annotations

import re
import subprocess
import sys


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


def test_the_input_modules_below_training_and_pipelines_import_no_torch_or_simulator():
    # run_inputs and stored_agents sit below training, pipelines and the API: they must not pull
    # a learner or pybullet in until a track or an agent is actually loaded
    code = ("import sys, d2a_core.run_inputs, d2a_core.stored_agents; "
            "print(sorted({'torch', 'pybullet', 'd2a_core.training.humans', 'd2a_core.training.assistant'} & set(sys.modules)))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"


def test_the_cli_starts_without_importing_torch_or_the_simulator():
    # every subprocess call of `d2a` (store commands, --help, scripts) would otherwise pay seconds
    # of torch and pybullet import before doing anything; commands import them when they run
    code = "import sys, d2a_cli.main; print(sorted({'torch', 'pybullet', 'matplotlib'} & set(sys.modules)))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"
