"""A person at the wheel: `d2a drive`.

`controls` turns held keys (or a gamepad's axes) into the env's action; `script` reads timed key
presses for scripted, repeatable drives; `window` is the pygame window (top-down view of the race,
the assistant's intent estimate and intervention); `one_drive` runs one drive at the env's rate,
blends the assistant's action as training does, logs the episode as MCAP and stores it as a
`drive` artifact. Only `window` imports pygame (the `drive` extra).
"""
