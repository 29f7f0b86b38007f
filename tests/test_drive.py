"""`d2a drive`: a scripted person through the real window code (SDL's off-screen driver), alone
and with an assistant; the drive is a verified artifact whose log holds the scripted actions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from d2a_core.artifacts import Store
from d2a_core.drive.controls import Controls
from d2a_core.drive.script import load_script
from d2a_core.errors import UsageError
from d2a_core.sim.episode_log import read_episode
from d2a_test_helpers import copy_store

pytest.importorskip("pygame")
OFFSCREEN = {"SDL_VIDEODRIVER": "dummy"}
DT = 0.1


def _key_script(path: Path, tap: str, start: float, tap_s: float, seconds: float = 30.0) -> Path:
    """Full throttle until `start` - 0.5 s, a short steer each way, then a `tap_s` press of `tap`
    every second from `start`."""
    events = [{"t": 0.0, "down": "up"}, {"t": start - 0.5, "up": "up"}, {"t": 3.0, "down": "left"},
              {"t": 3.2, "up": "left"}, {"t": 5.0, "down": "d"}, {"t": 5.2, "up": "d"}]
    t = start
    while t < seconds:
        events += [{"t": round(t, 1), "down": tap}, {"t": round(t + tap_s, 1), "up": tap}]
        t += 1.0
    path.write_text(yaml.safe_dump(events))
    return path


def _stay_script(path: Path, seconds: float = 30.0) -> Path:
    """Throttle for 1.5 s, then 0.3 s of throttle each second: a car that follows and finishes."""
    return _key_script(path, "w", 2.0, 0.3, seconds)


def _creep_script(path: Path, seconds: float = 30.0) -> Path:
    """Throttle for 1 s, then a 0.3 s brake tap each second: a car that creeps along the
    straightaway for the whole `seconds`."""
    return _key_script(path, "down", 1.5, 0.3, seconds)


def _expected_human_actions(script: Path, steps: int) -> np.ndarray:
    """What the scripted keys ask for at each step, through the same controls."""
    events, controls, out = load_script(script), Controls(), []
    for k in range(steps):
        while events and events[0].t <= k * DT + 1e-9:
            event = events.pop(0)
            (controls.press if event.down else controls.release)(event.key)
        out.append(controls.action(DT))
    return np.array(out)


def test_keys_steer_gradually_and_accelerate_at_once():
    controls = Controls(steer_rate=4.0)
    controls.press("left")
    controls.press("up")
    steer = [controls.action(0.1)[0] for _ in range(4)]
    np.testing.assert_allclose(steer, [0.4, 0.8, 1.0, 1.0], atol=1e-6)  # 0.25 s to full lock
    assert controls.action(0.1)[1] == 1.0
    controls.release("left")
    controls.press("s")
    action = controls.action(0.1)
    assert action[0] == pytest.approx(0.6) and action[1] == 0.0  # throttle and brake cancel
    controls.release("up")
    assert controls.action(0.1)[1] == -1.0
    assert not controls.quit
    controls.press("escape")
    assert controls.quit


def test_a_bad_key_script_names_its_file_entry_and_field(tmp_path):
    bad = tmp_path / "keys.yaml"
    for text, message in (("[{t: 1, down: jump}]", "event 0: field 'down': unknown key 'jump'"),
                          ("[{t: -1, down: up}]", "event 0: field 't' must be seconds"),
                          ("[{t: 0, down: up}, {t: 2, hold: up}]", "event 1: unknown field(s) ['hold']"),
                          ("{t: 0}", "expected a list")):
        bad.write_text(text)
        with pytest.raises(UsageError, match=str(bad)) as info:
            load_script(bad)
        assert message in str(info.value)


def test_without_a_display_drive_exits_2_and_says_how_to_run_it(cli, tmp_path, pair_store_template):
    res = cli("drive", "--intent", "stay", "--track", "straightaway", "--json", store=pair_store_template,
              env={"SDL_VIDEODRIVER": "", "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert res.code == 2, res.stderr
    assert "no display" in res.json["error"]["message"] and "SDL_VIDEODRIVER=dummy" in res.json["error"]["message"]


def test_a_scripted_drive_alone_is_stored_with_the_scripted_actions(cli, tmp_path, pair_store_template):
    store_dir = copy_store(pair_store_template, tmp_path)
    script = _creep_script(tmp_path / "creep.yaml")
    shot = tmp_path / "frame.png"
    args = ("drive", "--intent", "stay", "--track", "straightaway", "--script", str(script), "--seconds", "30",
            "--participant", "p01", "--trial", "1", "--json")
    res = cli(*args, "--screenshot", str(shot), store=store_dir, env=OFFSCREEN)
    assert res.code == 0, res.stderr
    drive = res.json
    assert drive["intent"] == "stay" and drive["assistant"] is None and drive["participant"] == "p01"
    steps = int(drive["metrics"]["steps"])
    assert steps == 300  # 30 s of race at 10 Hz, ended by --seconds
    assert drive["metrics"]["off_track"] == 0.0 and drive["metrics"]["collision"] == 0.0

    store = Store(store_dir)
    art = store.get(drive["id"])
    assert art.kind == "drive" and art.labels["participant"] == "p01" and art.labels["intent"] == "stay"
    listed = cli("artifacts", "ls", "--kind", "drive", "--json", store=store_dir)
    assert listed.code == 0 and [a["id"] for a in listed.json["artifacts"]] == [art.id]
    assert cli("artifacts", "verify", art.id, "--json", store=store_dir).code == 0

    episode = read_episode(store.path(art.id, "drive.mcap"))
    ego = episode.state["ego"]
    human = np.stack([ego["human_action.steer"], ego["human_action.accel"]], -1)[1:]
    applied = np.stack([ego["applied_action.steer"], ego["applied_action.accel"]], -1)[1:]
    np.testing.assert_allclose(human, _expected_human_actions(script, steps), atol=1e-6)
    np.testing.assert_allclose(applied, human, atol=1e-6)  # alone, the car executes the person's action
    assert set(ego["stated_intent"]) == {"stay"}
    assert episode.metadata["outcome"]["progress_m"] == pytest.approx(drive["metrics"]["progress_m"])

    # the frame shows the road and the red ego car in its middle
    import pygame

    image = pygame.surfarray.array3d(pygame.image.load(str(shot)))  # (width, height, 3)
    width, height = image.shape[:2]
    around = image[width // 2 - 20: width // 2 + 20, int(0.6 * height) - 25: int(0.6 * height) + 25]
    red = (around[..., 0] > 180) & (around[..., 1] < 100) & (around[..., 2] < 100)
    assert red.sum() > 100
    # the same script, seed and track give the same drive
    again = cli(*args, store=store_dir, env=OFFSCREEN)
    assert again.code == 0 and again.json["id"] == art.id


def test_a_drive_with_an_assistant_blends_its_action_and_logs_its_estimate(cli, tmp_path, trained_assistants):
    store_dir, trained = trained_assistants
    store_dir = copy_store(store_dir, tmp_path)
    assistant = next(a for a in trained["assistants"] if a["method"] == "dream2assist")["id"]
    script = _stay_script(tmp_path / "stay.yaml", seconds=8.0)
    res = cli("drive", "--intent", "stay", "--assistant", assistant, "--script", str(script), "--seconds", "8",
              "--json", store=store_dir, env=OFFSCREEN)
    assert res.code == 0, res.stderr
    drive = res.json
    assert drive["assistant"] == assistant and drive["method"] == "dream2assist"
    assert 0.0 <= drive["read_as_stated"] <= 1.0
    store = Store(store_dir)
    assert store.get(drive["id"]).inputs[1] == assistant
    ego = read_episode(store.path(drive["id"], "drive.mcap")).state["ego"]
    human = np.stack([ego["human_action.steer"], ego["human_action.accel"]], -1)[1:]
    assist = np.stack([ego["assistant_action.steer"], ego["assistant_action.accel"]], -1)[1:]
    applied = np.stack([ego["applied_action.steer"], ego["applied_action.accel"]], -1)[1:]
    np.testing.assert_allclose(human, _expected_human_actions(script, len(human)), atol=1e-6)
    assert np.abs(assist).max() > 0  # the assistant acted
    np.testing.assert_allclose(applied, np.clip(human + assist, -1, 1), atol=1e-5)
    estimate = np.stack([ego["intent_estimate.pass"], ego["intent_estimate.stay"]], -1)
    np.testing.assert_allclose(estimate.sum(-1), 1.0, atol=1e-5)
    assert drive["metrics"]["intervention"] == pytest.approx(np.linalg.norm(assist, axis=-1).mean(), rel=1e-5)
    # an intent outside the assistant's pair is a usage error
    res = cli("drive", "--intent", "left", "--assistant", assistant, "--script", str(script), "--json",
              store=store_dir, env=OFFSCREEN)
    assert res.code == 2 and "not one of the assistant's pair" in res.json["error"]["message"]


def test_a_study_asks_drives_pairs_and_reaches_the_report(cli, tmp_path, trained_assistants):
    """Two scripted trials on the same start, alone and with the assistant, the intent asked before
    each and checked after: two drives, a study whose table pairs them, and a report section."""
    store_dir, trained = trained_assistants
    store_dir = copy_store(store_dir, tmp_path)
    assistant = next(a for a in trained["assistants"] if a["method"] == "dream2assist")["id"]
    _stay_script(tmp_path / "stay.yaml", seconds=6.0)
    protocol = tmp_path / "study.yaml"
    protocol.write_text(yaml.safe_dump({"assistant": assistant, "seconds": 6, "trials": [
        {"intent": "ask", "assisted": False, "seed": 3, "script": "stay.yaml", "answers": ["s", "y"]},
        {"intent": "ask", "assisted": True, "seed": 3, "script": "stay.yaml", "answers": ["s", "n"]}]}))
    res = cli("study", "--protocol", str(protocol), "--participant", "p07", "--json", store=store_dir, env=OFFSCREEN)
    assert res.code == 0, res.stderr
    study = res.json
    assert [t["intent"] for t in study["trials"]] == ["stay", "stay"]
    assert [t["self_report"] for t in study["trials"]] == [True, False]
    assert [t["assisted"] for t in study["trials"]] == [False, True]
    store = Store(store_dir)
    drives = [store.get(t["drive"]) for t in study["trials"]]
    assert [d.labels["participant"] for d in drives] == ["p07", "p07"] and drives[1].inputs[1] == assistant
    assert store.get(study["id"]).inputs == [d.id for d in drives]
    (paired,) = study["table"]["paired"]
    change = study["trials"][1]["progress_m"] - study["trials"][0]["progress_m"]
    assert paired["pairs"] == 1 and paired["progress_change_m"] == pytest.approx(change)

    report = cli("report", "--out", str(tmp_path / "report"), "--json", store=store_dir)
    assert report.code == 0, report.stderr
    text = (tmp_path / "report" / "report.md").read_text()
    assert "Participant p07" in text and study["id"] in report.json["inputs"]

    protocol.write_text(yaml.safe_dump({"trials": [{"intent": "ask", "assisted": True}]}))
    res = cli("study", "--protocol", str(protocol), "--participant", "p07", "--json", store=store_dir, env=OFFSCREEN)
    assert res.code == 2 and "field 'assistant' is needed" in res.json["error"]["message"]
    protocol.write_text(yaml.safe_dump({"trials": [{"intent": "ask", "assisted": False, "sead": 1}]}))
    res = cli("study", "--protocol", str(protocol), "--participant", "p07", "--json", store=store_dir, env=OFFSCREEN)
    assert res.code == 2 and "trials.0.sead" in res.json["error"]["message"] and str(protocol) in res.json["error"]["message"]
