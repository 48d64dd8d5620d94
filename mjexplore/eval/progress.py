"""A terminal progress bar for one episode: simulated time, exploration ratio, decisions."""

from __future__ import annotations

import time
from typing import Any, TextIO

from mjexplore.io.progress import Progress


class EpisodeProgress:
    """An episode observer (see :class:`~mjexplore.episode.Episode`) that draws a bar of
    simulated time out of ``max_time``, with the exploration ratio and the number of
    decisions so far (:class:`~mjexplore.io.progress.Progress`, as every command shows
    progress).

    The bar is drawn only when ``stream`` is a terminal (a log file or pipe stays clean:
    ``explore`` prints its metrics when it ends), and redrawn at most once per
    ``min_interval`` seconds of wall time, so the episode loop pays next to nothing for it.

    Args:
        max_time: The episode's time cap, simulated seconds (the bar's total).
        stream: Where the bar goes (default: ``sys.stderr`` at construction time).
        min_interval: Wall-clock seconds between redraws.
    """

    def __init__(self, max_time: float, stream: TextIO | None = None,
                 min_interval: float = 0.25) -> None:
        self.progress = Progress(max_time, "explore", "s simulated", stream, every=None,
                                 min_interval=min_interval,
                                 bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                                 "{n:.0f}/{total:.0f} s simulated [{elapsed}<{remaining}"
                                 "{postfix}]")
        self.enabled = self.progress.terminal
        self.min_interval = min_interval
        self._next_draw = 0.0
        self._episode: Any = None

    def _draw(self) -> None:
        episode = self._episode
        self.progress.detail_text = (f"ratio {episode.ratio:.1%}, decisions "
                                     f"{sum(len(a.goals) for a in episode.agents)}")
        self.progress.set(min(episode.time, self.progress.total))

    def on_scan(self, agent, scan) -> None:
        self._episode = agent.episode

    def on_decision(self, agent, state) -> None:
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
        self.progress.close()


__all__ = ["EpisodeProgress"]
