"""Hard limits on track inputs, so that nonsense fails with a located error instead of a
MemoryError, an overflow or a track no car can drive.

These are constants, not config values: every config value of the `tracks` section is part of
a track artifact's identity, and a sanity bound should not change the ids of existing tracks.
"""

from __future__ import annotations

# more samples than this is a mistake (1000 km of road at 0.5 m); it also bounds memory
MAX_SAMPLES = 2_000_000
# coordinates beyond this (1000 km from the origin) lose precision in float32 renderers and overflow squares
MAX_COORD_M = 1.0e6
# steeper than this no road car climbs (the steepest public roads are about 35 %)
MAX_GRADE = 0.35
