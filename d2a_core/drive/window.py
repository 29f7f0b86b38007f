"""The drive window (pygame): the race from above, turned so the car drives up the screen, with
the numbers a person needs while driving and what the assistant is doing.

`display_problem()` says why no window can open (exit 2 in the CLI); with SDL's dummy video driver
(`SDL_VIDEODRIVER=dummy`) the window is drawn off-screen, which is how tests and scripted drives
run it. Scripted key presses (`script.load_script`) are posted as real key events, so they pass
through the same event handling as a keyboard's.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from d2a_core.drive.controls import Controls
from d2a_core.drive.script import KeyEvent
from d2a_core.errors import UsageError

CAR_LENGTH_M, CAR_WIDTH_M = 4.6, 1.9
COLOURS = {"background": (34, 40, 34), "road": (70, 70, 74), "edge": (235, 235, 235), "finish": (250, 250, 250),
           "ego": (220, 60, 50), "opponent": (60, 120, 220), "text": (240, 240, 240), "bar": (90, 90, 96),
           "human": (240, 200, 60), "assistant": (80, 220, 140)}


def display_problem() -> str | None:
    """Why a window cannot open here, or None."""
    try:
        import pygame  # noqa: F401
    except ImportError:
        return "d2a drive needs pygame: pip install 'd2a[drive]'"
    if sys.platform.startswith("linux") and not (os.environ.get("SDL_VIDEODRIVER") or os.environ.get("DISPLAY")
                                                   or os.environ.get("WAYLAND_DISPLAY")):
        return ("no display: run it on a desktop (DISPLAY or WAYLAND_DISPLAY), or set "
                "SDL_VIDEODRIVER=dummy for an off-screen, scripted drive (--script)")
    return None


def _pygame():
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # keep stdout for --json
    import pygame

    return pygame


class DriveWindow:
    """A window that follows the ego car. `poll` turns key (and scripted) events into `controls`;
    `draw` paints one frame."""

    def __init__(self, track, controls: Controls, script: Sequence[KeyEvent] = (), size: tuple[int, int] = (900, 640),
                 px_per_m: float = 7.0, title: str = "d2a drive") -> None:
        problem = display_problem()
        if problem is not None:
            raise UsageError(problem)
        self.pygame = pg = _pygame()
        pg.display.init()
        pg.font.init()
        self.screen = pg.display.set_mode(size)
        pg.display.set_caption(title)
        self.font = pg.font.Font(None, 24)
        self.small = pg.font.Font(None, 20)
        self.size, self.scale = size, px_per_m
        self.answers: list[str] = []  # scripted answers to `ask`, in order
        self._open_joystick()
        self.start(track, controls, script)

    def start(self, track, controls: Controls, script: Sequence[KeyEvent] = ()) -> None:
        """Begin a drive on `track` with fresh `controls` and its own key script."""
        self.controls = controls
        self.script = list(script)
        self.pygame.event.clear()
        left, right = track.edges()
        self.left, self.right = left[:, :2], right[:, :2]
        finish = np.asarray(track.finish_line_points(), float)
        self.finish = finish[:, :2] if finish.ndim == 2 and len(finish) >= 2 else None

    def _open_joystick(self) -> None:
        pg = self.pygame
        self.joystick = None
        pg.joystick.init()
        if pg.joystick.get_count() > 0:
            self.joystick = pg.joystick.Joystick(0)
            self.joystick.init()

    # --- input
    def poll(self, t: float) -> bool:
        """Post the script's events due by race time `t`, then handle the event queue. Returns
        whether the person asked to stop (window closed, Escape or Q)."""
        pg = self.pygame
        while self.script and self.script[0].t <= t + 1e-9:
            event = self.script.pop(0)
            kind = pg.KEYDOWN if event.down else pg.KEYUP
            pg.event.post(pg.event.Event(kind, key=pg.key.key_code(event.key)))
        closed = False
        for event in pg.event.get():
            if event.type == pg.QUIT:
                closed = True
            elif event.type == pg.KEYDOWN:
                self.controls.press(pg.key.name(event.key))
            elif event.type == pg.KEYUP:
                self.controls.release(pg.key.name(event.key))
        if self.joystick is not None:
            # left stick: x steers (right is +, the env's steer is + left), y accelerates (up is -)
            self.controls.set_axes(-self.joystick.get_axis(0), -self.joystick.get_axis(1))
        return closed or self.controls.quit

    # --- drawing
    def _to_screen(self, points: np.ndarray, centre: tuple[float, float], yaw: float) -> np.ndarray:
        """World (x, y) -> pixels, the ego at 60 % of the height, its heading up the screen."""
        d = np.asarray(points, float) - np.asarray(centre, float)
        c, s = math.cos(math.pi / 2 - yaw), math.sin(math.pi / 2 - yaw)
        x = c * d[..., 0] - s * d[..., 1]
        y = s * d[..., 0] + c * d[..., 1]
        w, h = self.size
        return np.stack([w / 2 + x * self.scale, h * 0.6 - y * self.scale], -1)

    def _car(self, pose: Sequence[float], centre, yaw: float, colour) -> None:
        x, y, heading = pose[0], pose[1], pose[2]
        hl, hw = CAR_LENGTH_M / 2, CAR_WIDTH_M / 2
        c, s = math.cos(heading), math.sin(heading)
        corners = [(x + c * a - s * b, y + s * a + c * b) for a, b in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
        self.pygame.draw.polygon(self.screen, colour, self._to_screen(np.array(corners), centre, yaw).tolist())

    def _bar(self, x: int, y: int, label: str, value: float, colour, signed: bool = False, width: int = 160) -> None:
        pg = self.pygame
        pg.draw.rect(self.screen, COLOURS["bar"], (x + 90, y, width, 14))
        if signed:
            half = width // 2
            length = int(round(half * max(-1.0, min(1.0, value))))
            start = x + 90 + half + min(0, length)
            pg.draw.rect(self.screen, colour, (start, y, abs(length), 14))
        else:
            pg.draw.rect(self.screen, colour, (x + 90, y, int(round(width * max(0.0, min(1.0, value)))), 14))
        self.screen.blit(self.small.render(label, True, COLOURS["text"]), (x, y))

    def draw(self, cars: Mapping[str, Sequence[float]], hud: Mapping[str, object]) -> None:
        """One frame: `cars` name -> (x, y, yaw), "ego" followed; `hud`: t, speed, progress, gap,
        stated intent, and with an assistant its `belief` (intent -> p), `human_action`,
        `assistant_action`."""
        pg = self.pygame
        ego = cars["ego"]
        centre, yaw = (ego[0], ego[1]), ego[2]
        self.screen.fill(COLOURS["background"])
        left = self._to_screen(self.left, centre, yaw)
        right = self._to_screen(self.right, centre, yaw)
        road = np.concatenate([left, right[::-1]])
        pg.draw.polygon(self.screen, COLOURS["road"], road.tolist())
        pg.draw.lines(self.screen, COLOURS["edge"], False, left.tolist(), 2)
        pg.draw.lines(self.screen, COLOURS["edge"], False, right.tolist(), 2)
        if self.finish is not None:
            pg.draw.lines(self.screen, COLOURS["finish"], False, self._to_screen(self.finish, centre, yaw).tolist(), 4)
        for name, pose in cars.items():
            if name != "ego":
                self._car(pose, centre, yaw, COLOURS["opponent"])
        self._car(ego, centre, yaw, COLOURS["ego"])

        lines = [f"t {hud.get('t', 0.0):5.1f} s   {3.6 * float(hud.get('speed', 0.0)):5.0f} km/h",
                 f"progress {float(hud.get('progress', 0.0)):5.0f} m   opponent {float(hud.get('gap', 0.0)):+5.0f} m",
                 f"your intent: {hud.get('intent') or '-'}"]
        if "assistant_action" in hud:  # how hard the assistant intervenes now
            lines.append(f"assistant ||a_A|| {float(np.linalg.norm(hud['assistant_action'])):4.2f}")
        for i, line in enumerate(lines):
            self.screen.blit(self.font.render(line, True, COLOURS["text"]), (12, 10 + 24 * i))
        y = 14 + 24 * len(lines)
        for name, p in (hud.get("belief") or {}).items():
            self._bar(12, y, f"reads {name}", float(p), COLOURS["assistant"])
            y += 20
        if hud.get("human_action") is not None:
            human, assist = np.asarray(hud["human_action"]), np.asarray(hud.get("assistant_action", (0.0, 0.0)))
            for label, value, colour in (("you: steer", -human[0], COLOURS["human"]),
                                         ("you: accel", human[1], COLOURS["human"]),
                                         ("aid: steer", -assist[0], COLOURS["assistant"]),
                                         ("aid: accel", assist[1], COLOURS["assistant"])):
                if label.startswith("aid") and "assistant_action" not in hud:
                    continue
                self._bar(12, y, label, float(value), colour, signed=True)
                y += 20
        pg.display.flip()

    def ask(self, question: str, options: Mapping[str, str]) -> str:
        """Show `question` and wait for one of the `options` keys; returns its value. Escape or
        closing the window stops (UsageError). A scripted answer, when queued, is posted as its key."""
        pg = self.pygame
        pg.event.clear()
        if self.answers:
            pg.event.post(pg.event.Event(pg.KEYDOWN, key=pg.key.key_code(self.answers.pop(0))))
        self.screen.fill(COLOURS["background"])
        for i, line in enumerate([question, "   ".join(f"[{k.upper()}] {v}" for k, v in options.items())]):
            text = self.font.render(line, True, COLOURS["text"])
            self.screen.blit(text, (self.size[0] // 2 - text.get_width() // 2, self.size[1] // 2 - 30 + 34 * i))
        pg.display.flip()
        while True:
            event = pg.event.wait(100)
            if event.type == pg.QUIT:
                raise UsageError("the window was closed; the study stopped")
            if event.type == pg.KEYDOWN:
                key = pg.key.name(event.key)
                if key == "escape":
                    raise UsageError("Escape pressed; the study stopped")
                if key in options:
                    return options[key]

    def screenshot(self, path: Path) -> None:
        """The last frame as a PNG."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.pygame.image.save(self.screen, str(path))

    def close(self) -> None:
        self.pygame.display.quit()
