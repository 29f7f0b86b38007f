"""Task and intent rewards of the paper (section 3.1 and appendix "Human Objectives").

Notation: `s` distance along the centreline, `e` lateral offset (positive = left);
`ds_t = s_ego - s_opp`, `de_t = e_ego - e_opp`. All constants come from `RewardConfig`.

The paper's formulas (its appendix), and what this module computes:

- task:  r_collision * I(collision) + r_bounds * I(off track) + r_finish * I(finish)
         (the paper gives only the signs; here -100, -100, +100, and nothing else: r^task is
         bounded, and the assistant receives it too)
- pass:  c_pass * (ds_t - ds_{t-1}) * I(|ds_t| <= W_pass or |ds_{t-1}| <= W_pass)
         + c_pass * F * I(crash)                                            [F: the forfeit, below]
- stay:  (s_t - s_{t-1}) + c_stay * (ds_t - ds_{t-1}) * I(|ds_t| <= W_stay or |ds_{t-1}| <= W_stay)
- left:  c_side * (ds_t - ds_{t-1}) * I(pass window) + (min(de_t, cap) + c_margin) * I(racing it)
         + c_side * F * I(crash)
- right: c_side * (ds_t - ds_{t-1}) * I(pass window) + (min(-de_t, cap) + c_margin) * I(racing it)
         + c_side * F * I(crash)
         I(racing it) = the opponent is still racing and ds_t >= -side_max_behind_m
         cap = side_cap_m (the paper: no cap)
         (the paper prints `- (de_t + 0.3)`; see `right_mirrors_left`)

"crash" is a collision or leaving the track: both end the episode.

**The forfeit F.** With the paper's constant crash penalty alone, a pass driver that is behind
ends its stream of negative passing reward by crashing (early in training every episode ends
early anyway, and the earliest end loses the least). A crash must cost at least what stopping
would. A car stopped at the crash point would go on paying the passing term while the opponent
drives on, for as long as the gap stays inside the +-W_pass window (or until the time limit):

    F = -| [ds_t - D, ds_t]  intersect  [-W_pass, W_pass] |      D = distance the opponent still
                                                                      drives until the time limit

so a crash costs exactly |r_collision| (or |r_bounds|) more than stopping, whatever replay was
drawn, and never more than c * 2 W_pass. The forfeit belongs to the intent term, at the intent's
own rate: 10 per metre for pass, 1 for left/right. Stay gets none: its windowed term pays a
stopped car for dropping back, so stopping is never a way out of a negative stream for it, and
the crash penalty alone already makes any crash worse than stopping. (An earlier form charged
r^task the full distance D at the pass rate for every intent: with the opponent moved on at its
last speed to the time limit, -20,000 on the straightaway and -42,700 on the hairpin against
+321 for a flat-out pass, shrinking every other reward ~100-fold under DreamerV3's percentile
return normalisation. `forfeit: false` restores the paper's literal sparse penalties.)

**The side term.** The paper pays left `de_t + 0.3` and right `-(de_t + 0.3)`: left earns 0.3 per
step for free, right pays 0.3 per step (so for right, ending the episode early pays). The two
intents are the same driver with the side flipped, so right here is the mirror of left,
`-de_t + 0.3`; `right_mirrors_left: false` restores the literal print.

The paper pays the side term on every step. Two ways of collecting it without racing: a car
parked beside the grid until the time limit (hence: only while the opponent races), and a car
that drops back and drives to the finish far behind the opponent, on its side, collecting the
side term for as long as the opponent races while the passing term charges only 1 per metre
lost (our quick left drivers of 2026-12-01 learnt this: 100 % finished, 94 % of steps on the
left, 72 % of them more than 30 m behind). A side is held only while racing the opponent, so the
term is paid only within `side_max_behind_m` behind it (the grid gap is 15 m);
`side_max_behind_m: null` and `side_only_while_racing: false` restore the literal formula.

The paper's side term grows without bound with the lateral gap, so the best place to be is the
road's very edge: our quick left drivers (2026-12-01, seeds 0-4) steered off the open left edge
for 12-25k steps and 3 of 5 never learnt to stop there (right drivers start on their side with a
barrier beyond the edge and did not). Being on a side is a matter of a car width and some margin,
not of metres more: the gap pays up to `side_cap_m` (2.5 m: the 1.9 m car and 0.6 m between the
two cars' sides) and nothing beyond. `side_cap_m: null` restores the uncapped term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from pydantic import Field

from d2a_core.config.section import Section

INTENTS = ("pass", "stay", "left", "right")


class RewardConfig(Section):
    """Task and intent reward constants (paper section 3 and appendix 'Human Objectives')."""

    collision: float = Field(-100.0, le=0, description="r^collision, paid once when a collision ends the episode")
    bounds: float = Field(-100.0, le=0, description="r^bounds, paid once when the car leaves the track too far")
    forfeit: bool = Field(
        True,
        description="a crash also pays the intent's passing rate on what a stopped car would still lose "
                    "inside the pass window (see the module docstring); false: the paper's literal penalties",
    )
    finish: float = Field(100.0, ge=0, description="r^finish, paid once when the finish line is reached")
    c_pass: float = Field(10.0, description="scale of the pass term on ds_t - ds_{t-1}")
    pass_window_m: float = Field(800.0, gt=0, description="s_high = -s_low of the pass indicator")
    c_stay: float = Field(-2.0, description="scale of the stay term on ds_t - ds_{t-1}")
    stay_window_m: float = Field(50.0, gt=0, description="s_high = -s_low of the stay indicator")
    c_side: float = Field(1.0, description="scale of the passing term of the left/right intents")
    c_margin: float = Field(0.3, description="lateral margin added to de_t by the left/right intents")
    # The paper pays the side term on every step. Once the opponent has finished there is no
    # "its left" any more, and a car parked beside the start grid would go on collecting
    # (de + c_margin) until the time limit: our quick left drivers learnt exactly that (a parked
    # car out-earned a finishing one). False restores the paper's literal formula.
    side_only_while_racing: bool = Field(
        True, description="pay the left/right side term only while the opponent is still racing"
    )
    side_max_behind_m: Optional[float] = Field(
        30.0, gt=0, description="pay the left/right side term only within this far behind the opponent (null: always)"
    )
    side_cap_m: Optional[float] = Field(
        2.5, gt=0, description="the left/right side term pays the lateral gap up to this many metres (null: no cap)"
    )
    right_mirrors_left: bool = Field(
        True, description="right pays -de + c_margin (the mirror of left); false: the paper's -(de + c_margin)"
    )


@dataclass(frozen=True)
class StepQuantities:
    """What the rewards of one control step depend on."""

    s: float
    s_prev: float
    ds: float
    ds_prev: float
    de: float
    collision: bool
    off_track: bool
    finished: bool
    remaining_m: float = 0.0  # distance the opponent still drives until the time limit (D)
    opponent_racing: bool = True  # False once the opponent's replay has reached its end


@dataclass(frozen=True)
class RewardTerms:
    """Every term of one step, so any objective's return can be computed from logs."""

    collision: float
    bounds: float
    finish: float
    task: float
    progress: float
    pass_: float
    stay: float
    left: float
    right: float
    forfeit_m: float = 0.0  # F of the module docstring (metres; 0 unless the step crashed)

    @staticmethod
    def zeros() -> "RewardTerms":
        """All terms zero (the layout of a step that has no terms yet)."""
        return RewardTerms(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def intent(self, name: str) -> float:
        return {"pass": self.pass_, "stay": self.stay, "left": self.left, "right": self.right}[name]

    def human(self, intent: Optional[str]) -> float:
        """r^H = r^task + r^y (just r^task when no intent is given)."""
        return self.task + (self.intent(intent) if intent else 0.0)

    def as_dict(self) -> dict[str, float]:
        return {
            "collision": self.collision, "bounds": self.bounds, "finish": self.finish, "task": self.task,
            "progress": self.progress, "pass": self.pass_, "stay": self.stay, "left": self.left,
            "right": self.right, "forfeit_m": self.forfeit_m,
        }


def _windowed_delta(q: StepQuantities, window: float) -> float:
    inside = -window <= q.ds <= window or -window <= q.ds_prev <= window
    return (q.ds - q.ds_prev) if inside else 0.0


def forfeit_m(q: StepQuantities, window: float) -> float:
    """F of the module docstring: minus the metres of gap a car stopped at this point would still
    lose inside the +-`window` pass window before the time limit (0 unless the step crashed)."""
    if not (q.collision or q.off_track):
        return 0.0
    lost = min(q.ds, window) - max(q.ds - max(q.remaining_m, 0.0), -window)
    return -max(lost, 0.0)


def task_reward(q: StepQuantities, cfg: RewardConfig) -> tuple[float, float, float]:
    """(r_collision, r_bounds, r_finish) for this step."""
    return (
        cfg.collision if q.collision else 0.0,
        cfg.bounds if q.off_track else 0.0,
        cfg.finish if q.finished else 0.0,
    )


def intent_reward(intent: str, q: StepQuantities, cfg: RewardConfig) -> float:
    """r^y of one intent for this step."""
    return reward_terms(q, cfg).intent(intent)


def reward_terms(q: StepQuantities, cfg: RewardConfig) -> RewardTerms:
    collision, bounds, finish = task_reward(q, cfg)
    progress = q.s - q.s_prev
    forfeit = forfeit_m(q, cfg.pass_window_m) if cfg.forfeit else 0.0
    passing = _windowed_delta(q, cfg.pass_window_m) + forfeit
    side = cfg.c_side * passing
    racing = (q.opponent_racing or not cfg.side_only_while_racing) and \
        (cfg.side_max_behind_m is None or q.ds >= -cfg.side_max_behind_m)
    cap = math.inf if cfg.side_cap_m is None else cfg.side_cap_m
    left_bias = (min(q.de, cap) + cfg.c_margin) if racing else 0.0
    if cfg.right_mirrors_left:
        right_bias = (min(-q.de, cap) + cfg.c_margin) if racing else 0.0
    else:
        right_bias = -(q.de + cfg.c_margin) if racing else 0.0
    return RewardTerms(
        collision=collision,
        bounds=bounds,
        finish=finish,
        task=collision + bounds + finish,
        progress=progress,
        pass_=cfg.c_pass * passing,
        stay=progress + cfg.c_stay * _windowed_delta(q, cfg.stay_window_m),
        left=side + left_bias,
        right=side + right_bias,
        forfeit_m=forfeit,
    )
