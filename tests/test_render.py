"""`d2a render`: GIF and MP4 of a smoke assistant beside a driver, and of a driver alone."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

ASSISTANT = "assistants/straightaway/pass-stay/dream2assist/seed0"
EGO_BLUE = np.array([0x1F, 0x77, 0xB4])


def _blue_pixels(frame: np.ndarray) -> int:
    return int((np.abs(frame[:, :, :3].astype(int) - EGO_BLUE).sum(axis=2) < 30).sum())


def test_an_assistant_renders_as_gif_and_mp4(trained_assistants, tmp_path, cli):
    store, _ = trained_assistants
    gif = tmp_path / "assist.gif"
    res = cli("render", ASSISTANT, "--out", str(gif), "--human", "humans/straightaway/stay", "--json", store=store)
    assert res.code == 0, res.stderr
    assert res.json["panels"][0].startswith("stay driver") and "dream2assist" in res.json["panels"][1]
    image = Image.open(gif)
    assert image.n_frames == res.json["frames"] > 10
    assert image.size == (800, 400)  # two panels side by side
    image.seek(5)
    frame = np.asarray(image.convert("RGB"))
    # the car is drawn in both panels (the view follows it, so it sits mid-panel)
    assert _blue_pixels(frame[:, :400]) > 50 and _blue_pixels(frame[:, 400:]) > 50
    # the same episode start again gives the same video
    again = tmp_path / "again.gif"
    assert cli("render", ASSISTANT, "--out", str(again), "--human", "humans/straightaway/stay", store=store).code == 0
    assert again.read_bytes() == gif.read_bytes()

    imageio = pytest.importorskip("imageio.v2")
    mp4 = tmp_path / "assist.mp4"
    res = cli("render", ASSISTANT, "--out", str(mp4), "--json", store=store)
    assert res.code == 0, res.stderr
    assert mp4.read_bytes()[4:8] == b"ftyp"
    reader = imageio.get_reader(mp4, format="FFMPEG")
    assert reader.count_frames() == res.json["frames"] and reader.get_data(0).shape == (400, 800, 3)
    reader.close()


def test_a_driver_renders_alone_and_bad_requests_say_why(trained_assistants, tmp_path, cli):
    store, _ = trained_assistants
    out = tmp_path / "alone.gif"
    res = cli("render", "humans/straightaway/pass/expert", "--out", str(out), "--seed", "3", "--json", store=store)
    assert res.code == 0, res.stderr
    assert Image.open(out).size == (400, 400) and len(res.json["panels"]) == 1
    bad = cli("render", ASSISTANT, "--out", str(tmp_path / "x.avi"), "--json", store=store)
    assert bad.code == 2 and ".gif or .mp4" in bad.json["error"]["message"]
    missing = cli("render", "no-such-thing", "--out", str(tmp_path / "y.gif"), "--json", store=store)
    assert missing.code != 0 and "no-such-thing" in missing.json["error"]["message"]
    track = cli("render", "track/straightaway", "--out", str(tmp_path / "z.gif"), "--json", store=store)
    assert track.code == 2 and "track artifact" in track.json["error"]["message"]
    assert not list(tmp_path.glob("*.tmp*")) and not (tmp_path / "x.avi").exists()
