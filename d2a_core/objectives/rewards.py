"""Task and intent rewards of the paper (section 3.1 and appendix "Human Objectives").

Notation: `s` distance along the centreline, `e` lateral offset (positive = left);
`ds_t = s_ego - s_opp`, `de_t = e_ego - e_opp`. All constants come from `RewardConfig`.

- task:  (r_collision + r_forfeit * D) * I(collision) + (r_bounds + r_forfeit * D) * I(off track)
         + r_finish * I(finish), D = how far the opponent still drives until the time limit
- pass:  c_pass * (ds_t - ds_{t-1}) * I(|ds_t| <= W_pass or |ds_{t-1}| <= W_pass)
- stay:  (s_t - s_{t-1}) + c_stay * (ds_t - ds_{t-1}) * I(|ds_t| <= W_stay or |ds_{t-1}| <= W_stay)
- left:  c_side * (ds_t - ds_{t-1}) * I(pass window) + (de_t + c_margin) * I(opponent racing)
- right: c_side * (ds_t - ds_{t-1}) * I(pass window) - (de_t + c_margin) * I(opponent racing)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from pydantic import Field

from d2a_core.config.section import Section

INTENTS = ("pass", "stay", "left", "right")


class RewardConfig(Section):
    """Task and intent reward constants (paper section 3 and appendix 'Human Objectives')."""

    # The paper gives only the signs of the task terms. With a constant penalty alone, a pass
    # driver that is behind ends the stream of negative passing reward by crashing: before it
    # can drive, every episode ends early anyway, and the earliest end loses the least. A crashed
    # car stays where it is while the opponent drives on, so the crash also pays, at the pass
    # term's rate, the distance the opponent still covers until the time limit (not capped by the
    # pass window, so no crash beats stopping). A pass episode that ends in a crash at s then
    # returns 10 * s + const: every metre driven counts, and any finish beats any crash.
    collision: float = Field(-100.0, le=0, description="r^collision, paid once when a collision ends the episode")
    bounds: float = Field(-100.0, le=0, description="r^bounds, paid once when the car leaves the track too far")
    forfeit_per_m: float = Field(
        -10.0, le=0,
        description="added to r^collision / r^bounds per metre the opponent still drives until the time limit",
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
    remaining_m: float = 0.0  # distance the opponent still drives until the time limit
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

    def intent(self, name: str) -> float:
        return {"pass": self.pass_, "stay": self.stay, "left": self.left, "right": self.right}[name]

    def human(self, intent: Optional[str]) -> float:
        """r^H = r^task + r^y (just r^task when no intent is given)."""
        return self.task + (self.intent(intent) if intent else 0.0)

    def as_dict(self) -> dict[str, float]:
        return {
            "collision": self.collision, "bounds": self.bounds, "finish": self.finish, "task": self.task,
            "progress": self.progress, "pass": self.pass_, "stay": self.stay, "left": self.left,
            "right": self.right,
        }


def _windowed_delta(q: StepQuantities, window: float) -> float:
    inside = -window <= q.ds <= window or -window <= q.ds_prev <= window
    return (q.ds - q.ds_prev) if inside else 0.0


def task_reward(q: StepQuantities, cfg: RewardConfig) -> tuple[float, float, float]:
    """(r_collision, r_bounds, r_finish) for this step."""
    forfeit = cfg.forfeit_per_m * max(q.remaining_m, 0.0)
    return (
        cfg.collision + forfeit if q.collision else 0.0,
        cfg.bounds + forfeit if q.off_track else 0.0,
        cfg.finish if q.finished else 0.0,
    )


def intent_reward(intent: str, q: StepQuantities, cfg: RewardConfig) -> float:
    """r^y of one intent for this step."""
    return reward_terms(q, cfg).intent(intent)


def reward_terms(q: StepQuantities, cfg: RewardConfig) -> RewardTerms:
    collision, bounds, finish = task_reward(q, cfg)
    progress = q.s - q.s_prev
    passing = _windowed_delta(q, cfg.pass_window_m)
    side = cfg.c_side * passing
    bias = (q.de + cfg.c_margin) if (q.opponent_racing or not cfg.side_only_while_racing) else 0.0
    return RewardTerms(
        collision=collision,
        bounds=bounds,
        finish=finish,
        task=collision + bounds + finish,
        progress=progress,
        pass_=cfg.c_pass * passing,
        stay=progress + cfg.c_stay * _windowed_delta(q, cfg.stay_window_m),
        left=side + bias,
        right=side - bias,
    )
