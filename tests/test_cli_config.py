"""Config presets, file and --set overrides, and every class of config error (exit 2)."""

from __future__ import annotations


def test_presets_and_override_order(cli, tmp_path):
    res = cli("config", "show", "--preset", "smoke", "--json")
    assert res.code == 0, res.stderr
    assert res.json["config"]["opponents"]["count"] == 2
    assert cli("config", "show", "--preset", "paper", "--json").json["config"]["opponents"]["count"] == 8

    user = tmp_path / "mine.yaml"
    user.write_text("opponents:\n  count: 5\n  pace_min: 0.8\nreward:\n  c_pass: 1e-1\n")
    res = cli("config", "show", "--preset", "smoke", "--config", str(user), "--set", "opponents.count=6",
              "--set", "reward.finish=20", "--json")
    assert res.code == 0, res.stderr
    cfg = res.json["config"]
    assert cfg["opponents"]["count"] == 6           # --set beats the file
    assert cfg["opponents"]["pace_min"] == 0.8      # the file beats the preset/defaults
    assert cfg["reward"]["c_pass"] == 0.1           # YAML 1.2 float syntax
    assert cfg["reward"]["finish"] == 20.0
    assert cfg["reward"]["c_stay"] == -2.0          # untouched default (the paper's value)
    assert res.json["sources"]["opponents.pace_min"] == str(user)
    assert res.json["sources"]["opponents.count"] == "--set opponents.count=6"


def test_unknown_key_names_key_value_and_file(cli, tmp_path):
    user = tmp_path / "typo.yaml"
    user.write_text("opponents:\n  cuont: 5\n")
    res = cli("config", "show", "--config", str(user), "--json")
    assert res.code == 2
    msg = res.json["error"]["message"]
    assert "opponents.cuont" in msg and "5" in msg and str(user) in msg and "opponents.count" in msg


def test_wrong_type_names_key_value_and_source(cli, tmp_path):
    res = cli("config", "show", "--set", "opponents.count=many", "--json")
    assert res.code == 2
    msg = res.json["error"]["message"]
    assert "opponents.count" in msg and "many" in msg and "--set opponents.count=many" in msg
    user = tmp_path / "t.yaml"
    user.write_text("reward:\n  finish: -3\n")
    res = cli("config", "show", "--config", str(user), "--json")
    assert res.code == 2 and "reward.finish" in res.json["error"]["message"] and str(user) in res.json["error"]["message"]


def test_bad_yaml_missing_file_bad_set_and_unknown_preset(cli, tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("opponents:\n  count: [1, 2\n")
    res = cli("config", "show", "--config", str(broken), "--json")
    assert res.code == 2 and f"{broken}:" in res.json["error"]["message"]
    res = cli("config", "show", "--config", str(tmp_path / "missing.yaml"), "--json")
    assert res.code == 2 and "missing.yaml" in res.json["error"]["message"]
    res = cli("config", "show", "--set", "opponents.count", "--json")
    assert res.code == 2 and "KEY.PATH=VALUE" in res.json["error"]["message"]
    res = cli("config", "show", "--preset", "huge", "--json")
    assert res.code == 2 and "smoke" in res.json["error"]["message"]
    not_mapping = tmp_path / "list.yaml"
    not_mapping.write_text("- 1\n- 2\n")
    assert cli("config", "show", "--config", str(not_mapping)).code == 2


def test_a_pairs_section_applies_to_its_pair_only(cli, tmp_path):
    """`pairs.<pair>` values take effect for that pair's runs (either order of its intents), over
    the layer they sit in and under the later ones; other runs do not see them."""
    shown = lambda *args: cli("config", "show", "--preset", "quick", *args, "--json")  # noqa: E731
    assert shown().json["config"]["assistant"]["reward"]["w_interv"] == 1.0
    assert shown("--pair", "pass-stay").json["config"]["assistant"]["reward"]["w_interv"] == 1.0
    for pair in ("left-right", "right-left"):
        res = shown("--pair", pair)
        assert res.code == 0, res.stderr
        assert res.json["config"]["assistant"]["reward"]["w_interv"] == 0.5
        assert res.json["sources"]["assistant.reward.w_interv"].endswith("pairs.left-right")

    user = tmp_path / "mine.yaml"
    user.write_text("assistant:\n  reward:\n    w_interv: 0.8\n"
                    "pairs:\n  pass-stay:\n    assistant:\n      reward:\n        w_interv: 0.25\n")
    assert shown("--config", str(user)).json["config"]["assistant"]["reward"]["w_interv"] == 0.8
    assert shown("--config", str(user), "--pair", "left-right").json["config"]["assistant"]["reward"]["w_interv"] == 0.8
    assert shown("--config", str(user), "--pair", "stay-pass").json["config"]["assistant"]["reward"]["w_interv"] == 0.25
    res = shown("--config", str(user), "--pair", "pass-stay", "--set", "assistant.reward.w_interv=0.3")
    assert res.json["config"]["assistant"]["reward"]["w_interv"] == 0.3


def test_a_bad_pairs_section_is_a_usage_error_naming_it(cli, tmp_path):
    """A typo in a pair's values fails on every run, not only on that pair's; so does a key that
    names no pair, and `--set pairs....`."""
    user = tmp_path / "pairs.yaml"
    user.write_text("pairs:\n  left-right:\n    assistant:\n      reward:\n        w_intrev: 0.5\n")
    res = cli("config", "show", "--config", str(user), "--pair", "pass-stay", "--json")
    assert res.code == 2
    msg = res.json["error"]["message"]
    assert "assistant.reward.w_intrev" in msg and f"{user}, pairs.left-right" in msg and "w_interv" in msg
    user.write_text("pairs:\n  left-up:\n    assistant:\n      env_steps: 10\n")
    res = cli("config", "show", "--config", str(user), "--json")
    assert res.code == 2 and "'left-up' is not an intent pair" in res.json["error"]["message"]
    user.write_text("pairs:\n  left-right: 3\n")
    assert cli("config", "show", "--config", str(user), "--json").code == 2
    res = cli("config", "show", "--set", "pairs.left-right.assistant.env_steps=10", "--json")
    assert res.code == 2 and "pairs" in res.json["error"]["message"]
    assert cli("config", "show", "--pair", "left-left", "--json").code == 2
