"""The version of the code that produces training results; part of every run key.

Bump `TRAINING_CODE_VERSION` in the same commit as any change that alters what a training run
produces for the same config and seed (rewards, environment, observation, learner, expert rule),
so that the next run trains afresh instead of returning a result made by older code. Changes that
only alter speed or float rounding (kernels, threading) do not bump it; the manifest's git commit
records those.

History:
- 1: everything up to d745ced (2026-11-30).
- 2: 2026-12-01: crash forfeit bounded by the pass window and moved into the intent terms;
  right mirrors left; a time-left input; a finished opponent shown far ahead; a finish off the
  road is no finish; actor(sg(s)) in imagination; the expert chosen by `evaluation.criteria`.
- 3: 2026-12-01: the left/right side term only within 30 m behind the opponent (changes left and
  right only; pass and stay train exactly as under 2).
- 4: 2026-12-01: the left/right side term pays the lateral gap only up to 2.5 m (changes left and
  right only; pass and stay train exactly as under 2 and 3).
"""

TRAINING_CODE_VERSION = 4
