"""Keyboard and gamepad input as the env's action [steer, accel] in [-1, 1].

Steering ramps toward the held direction at `steer_rate` per second and back to centre when no
direction is held: a keyboard is on/off, and a full-lock step at 10 Hz is a jerk no driver makes.
Accelerating and braking follow the keys directly (the car's own dynamics smooth them).
"""

from __future__ import annotations

import numpy as np

# key names as `pygame.key.name` gives them, and what each does
STEER_LEFT = frozenset({"left", "a"})
STEER_RIGHT = frozenset({"right", "d"})
THROTTLE = frozenset({"up", "w"})
BRAKE = frozenset({"down", "s"})
QUIT = frozenset({"escape", "q"})
DRIVING_KEYS = STEER_LEFT | STEER_RIGHT | THROTTLE | BRAKE


class Controls:
    """The person's action from the keys held now (or a gamepad's axes, which take precedence
    while they are off centre)."""

    def __init__(self, steer_rate: float = 4.0, deadzone: float = 0.08) -> None:
        if steer_rate <= 0:
            raise ValueError("steer_rate must be positive")
        self.steer_rate, self.deadzone = steer_rate, deadzone
        self.held: set[str] = set()
        self.steer = 0.0
        self.axes: tuple[float, float] | None = None  # gamepad (steer, accel), positive = left / forward

    def press(self, key: str) -> None:
        self.held.add(key)

    def release(self, key: str) -> None:
        self.held.discard(key)

    def set_axes(self, steer: float, accel: float) -> None:
        """A gamepad's stick (steer: positive left) and triggers (accel: throttle minus brake)."""
        self.axes = (float(steer), float(accel))

    @property
    def quit(self) -> bool:
        return bool(self.held & QUIT)

    def action(self, dt: float) -> np.ndarray:
        """The action for the next `dt` seconds, [steer (+ left), accel (+ throttle, - brake)]."""
        if self.axes is not None and max(abs(self.axes[0]), abs(self.axes[1])) > self.deadzone:
            self.steer = float(np.clip(self.axes[0], -1.0, 1.0))
            return np.array([self.steer, np.clip(self.axes[1], -1.0, 1.0)], np.float32)
        target = float(bool(self.held & STEER_LEFT)) - float(bool(self.held & STEER_RIGHT))
        step = self.steer_rate * dt
        self.steer = float(np.clip(target, self.steer - step, self.steer + step))
        accel = float(bool(self.held & THROTTLE)) - float(bool(self.held & BRAKE))
        return np.array([self.steer, accel], np.float32)
