"""Re-render a recorded session (the same renderer, the recorded inputs: deterministic).

A session recorded with ``--render-mode tracked``, ``auto`` or ``all_views`` is replayed with every
view of the same default cone (``all_views`` with every view rendered: what those frames
approximate, without depending on earlier frames).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from .session import LISTENER_KEYS, load_session

__all__ = ["replay_frames", "replay_session"]


def replay_frames(session: str | os.PathLike, tile_scale: float | None = None, every: int = 1) -> Iterator[np.ndarray]:
    """Native images (H, W, 3) uint8 of every ``every``-th recorded 25 fps frame."""
    from .render import LiveAvatarRenderer

    meta, tr = load_session(session)
    scale = float(tile_scale if tile_scale is not None else meta.get("settings", {}).get("tile_scale", 1.0))
    mode = str(meta.get("settings", {}).get("render_mode", "cone"))
    renderer = LiveAvatarRenderer(tile_scale=scale, native=True, preview=False, backend="fast",  # exact, any machine
                            mode="all_views" if mode in ("tracked", "auto") else mode,
                            view_step=1)  # offline: every view rendered, no synthesis
    scenario = None
    sc = meta.get("settings", {}).get("scenario")
    if sc:
        from .controls import Scenario

        try:
            scenario = Scenario.load(sc)
        except Exception:  # noqa: BLE001 - the scenario file may be gone: named expressions are then skipped
            scenario = None
    for t in range(0, len(tr["time_s"]), int(every)):
        lf = {k: tr[f"listener_{k}"][t] for k in LISTENER_KEYS}
        named = scenario.named_at(float(tr["time_s"][t])) if scenario is not None else ()
        # pain_shown >= 0: the behaviour layers drew the pain into listener_expr, add none on top
        pain = 0.0 if "pain_shown" in tr and tr["pain_shown"][t] >= 0 else float(tr["pain"][t])
        yield renderer.render(lf, pain, named, float(tr["viewer_angle_deg"][t]),
                              float(tr["viewer_distance_m"][t])).native


def replay_session(session: str | os.PathLike, out: str | os.PathLike, tile_scale: float | None = None,
                   every: int = 1) -> int:
    """Write the re-rendered session to ``out`` (mp4, 25 / every fps); returns the frame count."""
    from tqdm import tqdm

    from ..media import VideoWriter

    # verified before the rename (ffmpeg's exit status, decoded frame count): a full disk is an error
    with VideoWriter(Path(out), 25.0 / every, codec="libx264", quality=7, macro_block_size=8,
                     what="replay video") as writer:
        for img in tqdm(replay_frames(session, tile_scale, every), desc="replay", unit="frame"):
            writer.write(img)
    return writer.frames
