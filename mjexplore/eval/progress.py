"""A terminal progress bar for one episode: simulated time, exploration ratio, decisions."""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from tqdm import tqdm


class EpisodeProgress:
    """An episode observer (see :class:`~mjexplore.episode.Episode`) that draws a tqdm
    bar of simulated time out of ``max_time``, with the exploration ratio and the number
    of decisions so far.

    The bar is drawn only when ``stream`` is a terminal (a log file or pipe stays clean),
    and redrawn at most once per ``min_interval`` seconds of wall time, so the episode
    loop pays next to nothing for it.

    Args:
        max_time: The episode's time cap, simulated seconds (the bar's total).
        stream: Where the bar goes (default: ``sys.stderr`` at construction time).
        min_interval: Wall-clock seconds between redraws.
    """

    def __init__(self, max_time: float, stream: TextIO | None = None,
                 min_interval: float = 0.25) -> None:
        stream = sys.stderr if stream is None else stream
        isatty = getattr(stream, "isatty", None)
        self.enabled = bool(isatty and isatty())
        self.min_interval = min_interval
        self._next_draw = 0.0
        self._episode: Any = None
        self.bar = tqdm(total=max_time, file=stream, disable=not self.enabled, desc="explore",
                        mininterval=min_interval, bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                        "{n:.0f}/{total:.0f} s simulated [{elapsed}<{remaining}{postfix}]")

    def _draw(self) -> None:
        episode = self._episode
        self.bar.n = min(episode.sim.time, self.bar.total)
        self.bar.set_postfix_str(f"ratio {episode.curve[-1][1]:.1%}, "
                                 f"decisions {len(episode.goals)}", refresh=False)
        self.bar.refresh()

    def on_scan(self, episode, scan) -> None:
        self._episode = episode

    def on_decision(self, episode, state) -> None:
        pass

    def on_step(self, episode) -> None:
        if not self.enabled:
            return
        self._episode = episode
        now = time.monotonic()
        if now >= self._next_draw:
            self._next_draw = now + self.min_interval
            self._draw()

    def close(self) -> None:
        """Draws the final state and closes the bar (left on screen)."""
        if self.enabled and self._episode is not None:
            self._draw()
        self.bar.close()


__all__ = ["EpisodeProgress"]
