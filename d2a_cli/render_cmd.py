"""`d2a render`: an episode of a stored driver or assistant, or a stored episode log, as a GIF or MP4."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from d2a_cli.common import RunContext, out_console, with_common_options


@with_common_options
def render(
    ref: Annotated[str, typer.Argument(help="A human checkpoint or population, an assistant, an evaluation "
                                            "(id, prefix or alias) or an .mcap episode log file.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Video to write: .gif or .mp4 (MP4 needs d2a[video]).")],
    human: Annotated[Optional[str], typer.Option(
        "--human", help="For an assistant: the driver beside it (default: the pair's first intent's imperfect "
                        "checkpoint nearest 50 % of its expert).")] = None,
    episode: Annotated[Optional[str], typer.Option(
        "--episode", help="For an evaluation: the episode log's file name in it (default: its first assisted "
                          "episode).")] = None,
    fps: Annotated[float, typer.Option("--fps", min=1, max=60, help="Frames per second (the env steps at 10 Hz).")] = 10.0,
    *,
    run: RunContext,
) -> None:
    """Draw an episode from above, following the car: a driver alone; an assistant beside a driver
    (unassisted and assisted on the same start, with its intent estimate); or a stored episode.
    --seed picks the episode's start and opponent."""
    from d2a_core.pipelines.render import render as render_episode

    result = render_episode(run.store(), ref, out, human=human, seed=run.seed, episode=episode, fps=fps,
                            device=run.device)

    def show(r: dict[str, Any]) -> None:
        out_console.print(f"{r['out']}: {r['frames']} frames at {r['fps']:g} fps ({' | '.join(r['panels'])})",
                          highlight=False)

    run.emit(result, show)
