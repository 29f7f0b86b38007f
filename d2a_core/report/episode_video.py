"""Episode logs as a video: a top-down view that follows the ego car, one panel per episode.

Reads only the logs (`sim.episode_log.read_episode`) and the track's geometry; draws with
matplotlib (Agg) and writes a GIF with Pillow or an MP4 with imageio's ffmpeg (the `video`
extra). Panels side by side share the time axis, so an assisted episode and its unassisted twin
(same env seed: same start and opponent) can be compared frame by frame. An assisted log's
intent estimate is drawn as one bar per intent of the pair, the true intent marked.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from d2a_core.errors import UsageError

CAR_LENGTH_M, CAR_WIDTH_M = 4.6, 1.9
_EGO, _OPPONENT = "#1f77b4", "#7f7f7f"


def _car_outline(x: float, y: float, yaw: float) -> np.ndarray:
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [CAR_LENGTH_M / 2, CAR_WIDTH_M / 2]
    c, s = math.cos(yaw), math.sin(yaw)
    return corners @ np.array([[c, s], [-s, c]]) + [x, y]


def _field(episode, agent: str, name: str) -> np.ndarray | None:
    values = episode.state.get(agent, {}).get(name)
    return None if values is None else np.asarray(values, np.float64)


def frames(panels: Sequence[tuple[str, object]], track, view_m: float = 70.0, width_px: int = 400,
           height_px: int = 400) -> Iterator[np.ndarray]:
    """RGB frames (H, W, 3) of the episodes in `panels` ((title, Episode) pairs) side by side, one
    per logged step of the longest; a shorter episode holds its last frame."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    if not panels:
        raise UsageError("nothing to render")
    n = len(panels)
    fig = Figure(figsize=(width_px * n / 100, height_px / 100), dpi=100)
    FigureCanvasAgg(fig)
    left, right = track.edges()
    centre = track.centreline_points()
    finish = track.finish_line_points()
    artists = []
    for k, (title, episode) in enumerate(panels):
        ax = fig.add_subplot(1, n, k + 1)
        ax.set_facecolor("#3a7d44")
        road = np.vstack([left[:, :2], right[::-1, :2]])
        ax.add_patch(Polygon(road, closed=True, facecolor="#555555", edgecolor="white", linewidth=1.5))
        ax.plot(centre[:, 0], centre[:, 1], color="white", linewidth=0.6, linestyle=(0, (6, 6)))
        ax.plot(finish[:, 0], finish[:, 1], color="white", linewidth=3)
        for polyline, _ in track.barrier_polylines():
            ax.plot(polyline[:, 0], polyline[:, 1], color="#d62728", linewidth=2)
        ego = ax.add_patch(Polygon(np.zeros((4, 2)), closed=True, facecolor=_EGO, edgecolor="black", zorder=5))
        opp = ax.add_patch(Polygon(np.zeros((4, 2)), closed=True, facecolor=_OPPONENT, edgecolor="black", zorder=4))
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=10)
        text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", ha="left", fontsize=8, color="white",
                       family="monospace", zorder=10)
        intents = sorted(name.split(".", 1)[1] for name in episode.state.get("assistant", {})
                         if name.startswith("intent_probs."))
        probs = {i: _field(episode, "assistant", f"intent_probs.{i}") for i in intents}
        has_estimate = bool(intents) and all(np.isfinite(p).any() for p in probs.values())
        bars = None
        if has_estimate:
            inset = ax.inset_axes([0.62, 0.02, 0.36, 0.05 + 0.07 * len(intents)])
            bars = inset.barh(range(len(intents)), [0.0] * len(intents), color="#ff7f0e")
            inset.set_xlim(0, 1)
            inset.set_yticks(range(len(intents)), labels=intents, fontsize=8, color="white")
            inset.tick_params(axis="x", labelsize=6, colors="white")
            inset.set_facecolor((0, 0, 0, 0.4))
            inset.set_title("intent estimate", fontsize=8, color="white")
        true_intent = episode.metadata.get("intent", "")
        artists.append((ax, ego, opp, text, bars, intents, probs if has_estimate else {}, true_intent, episode))
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.02, top=0.92, wspace=0.05)
    length = max(len(episode) for _, episode in panels)
    for step in range(length):
        for ax, ego, opp, text, bars, intents, probs, true_intent, episode in artists:
            t = min(step, len(episode) - 1)
            x, y, _, yaw = episode.poses["ego"][t]
            ego.set_xy(_car_outline(x, y, yaw))
            if "opponent" in episode.poses:
                ox, oy, _, oyaw = episode.poses["opponent"][t]
                opp.set_xy(_car_outline(ox, oy, oyaw))
            ax.set_xlim(x - view_m / 2, x + view_m / 2)
            ax.set_ylim(y - view_m / 2, y + view_m / 2)
            lines = [f"t {episode.times[t]:5.1f} s"]
            for label, name, unit in (("speed", "speed", "m/s"), ("progress", "progress", "m"), ("gap", "ds", "m")):
                values = _field(episode, "ego", name)
                if values is not None:
                    lines.append(f"{label} {values[t]:6.1f} {unit}")
            steer, accel = (_field(episode, "ego", f"assistant_action.{k}") for k in ("steer", "accel"))
            if steer is not None and accel is not None and np.isfinite([steer[t], accel[t]]).all():
                lines.append(f"|a_A| {math.hypot(steer[t], accel[t]):5.2f}")
            if t == len(episode) - 1:
                outcome = episode.metadata.get("outcome") or {}
                if isinstance(outcome, dict):
                    ended = [k for k in ("finished", "collision", "off_track") if outcome.get(k)]
                    if ended:
                        lines.append(ended[0].replace("_", " "))
            text.set_text("\n".join(lines))
            if bars is not None:
                for bar, intent in zip(bars, intents):
                    bar.set_width(float(np.nan_to_num(probs[intent][t])))
                    bar.set_color("#2ca02c" if intent == true_intent else "#ff7f0e")
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())
        yield np.ascontiguousarray(rgba[:, :, :3])


def write_video(images: Iterator[np.ndarray], out: Path, fps: float = 10.0) -> int:
    """Write frames to `out` (.gif or .mp4); returns the frame count. The file appears whole or
    not at all."""
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise UsageError(f"--out {out}: the video must end in .gif or .mp4")
    tmp = out.with_name(f".{out.stem}.tmp{suffix}")  # the encoder goes by the extension
    count = 0
    try:
        if suffix == ".gif":
            from PIL import Image

            pictures = [Image.fromarray(frame) for frame in images]
            count = len(pictures)
            if not count:
                raise UsageError("nothing to render: the episode has no steps")
            buffer = io.BytesIO()
            pictures[0].save(buffer, format="GIF", save_all=True, append_images=pictures[1:],
                              duration=int(round(1000 / fps)), loop=0, optimize=False)
            tmp.write_bytes(buffer.getvalue())
        else:
            try:
                import imageio.v2 as imageio
                import imageio_ffmpeg  # noqa: F401 - the encoder imageio needs for MP4
            except ImportError:
                raise UsageError("MP4 needs imageio with ffmpeg: pip install 'd2a[video]' (or write a .gif)") from None
            with imageio.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264", macro_block_size=8,
                                    pixelformat="yuv420p", ffmpeg_log_level="error") as writer:
                for frame in images:
                    writer.append_data(frame)
                    count += 1
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return count
