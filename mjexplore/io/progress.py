"""How long work shows it is alive, the same way in every command.

On a terminal, a tqdm bar with the work's phase ("collecting", "updating", ...) and details
after it, redrawn at most a few times a second, whose clock keeps ticking while a phase runs
without updates (a PPO update, a held-out evaluation). Anywhere else (a pipe, a log file)
no bar and no carriage returns: a plain line at most every ``every`` seconds, at least every
``every`` seconds while the work runs (also through a phase without updates), and one at
the end, or nothing at all (``every=None``, as ``explore`` does). ``enabled=False`` (the
commands' ``--no-progress``) shows nothing anywhere.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

from tqdm import tqdm

HEARTBEAT_S = 30.0  # Off a terminal, the longest silence of lines at every update (every=0).
DEFAULT_FORMAT = ("{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} "
                  "[{elapsed}<{remaining}{postfix}]")


def is_terminal(stream: TextIO) -> bool:
    """Whether ``stream`` is a terminal (a bar may be drawn there)."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # A closed stream.
        return False


def _clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class Progress:
    """A progress display of ``total`` units of work (see the module docstring).

    Args:
        total: Units of work in all (the bar's end).
        desc: The work's name, first on the bar and on each line ("train", "bench").
        unit: The units' name, plural ("decisions", "episodes", "frames").
        stream: Where it goes (default: ``sys.stderr`` at construction time).
        enabled: False shows nothing.
        every: Off a terminal, seconds between plain lines (0: a line at every update or
            phase, and one after ``HEARTBEAT_S`` without any); None: no lines at all.
        bar_format: tqdm's format of the bar on a terminal.
        min_interval: Seconds between redraws of the bar.
        tick: Seconds between the ticker's :meth:`heartbeat` (a bar's clock, a line through
            a silent phase; at most ``every`` off a terminal); 0: no ticker.
        initial: Units of work done before (a resumed run's).
        phase: The first phase (see :meth:`phase`).
    """

    def __init__(self, total: float, desc: str, unit: str, stream: TextIO | None = None,
                 enabled: bool = True, every: float | None = 30.0,
                 bar_format: str = DEFAULT_FORMAT, min_interval: float = 0.25,
                 tick: float = 1.0, initial: float = 0, phase: str = "") -> None:
        self.stream = sys.stderr if stream is None else stream
        self.terminal = enabled and is_terminal(self.stream)
        self.lines = enabled and not self.terminal and every is not None
        self.enabled = self.terminal or self.lines
        self.desc, self.unit, self.every = desc, unit, every
        self.total, self.n = total, initial
        self.phase_text, self.detail_text = phase, ""
        self.start = time.monotonic()
        self._last_line = self.start
        self._printed = ""  # The last line's text; the first comes at once.
        self._closed = False
        self._lock = threading.Lock()
        self.bar = tqdm(total=total, initial=initial, file=self.stream,
                        disable=not self.terminal, desc=desc, unit=unit,
                        mininterval=min_interval, bar_format=bar_format, dynamic_ncols=True)
        self._line()  # Off a terminal, the first line says at once that the work started.
        self._stop = threading.Event()
        self._ticker = None
        # A bar's clock keeps ticking, and off a terminal a line comes at least every
        # `every` seconds, through a phase without updates too (a PPO update, an evaluation).
        period = 0.0 if tick <= 0 else tick if self.terminal else \
            min(tick, self.every or tick) if self.lines else 0.0
        if period > 0:
            self._ticker = threading.Thread(target=self._tick, args=(period,), daemon=True,
                                            name=f"{desc}-progress")
            self._ticker.start()

    def _tick(self, period: float) -> None:
        while not self._stop.wait(period):
            self.heartbeat()

    def heartbeat(self) -> None:
        """What the ticker does each period: redraws a bar (its clock), or off a terminal
        writes a line when none came for ``every`` seconds (:data:`HEARTBEAT_S` with
        ``every=0``)."""
        if self.terminal:
            self.bar.refresh()
        elif self.lines:
            with self._lock:
                self._write_line(False, self.every or HEARTBEAT_S)

    def _postfix(self) -> str:
        return ", ".join(t for t in (self.phase_text, self.detail_text) if t)

    def _line(self, force: bool = False) -> None:
        if not self.lines:
            return
        assert self.every is not None  # Lines are only written when `every` is set.
        with self._lock:  # The ticker's thread writes lines too.
            self._write_line(force, self.every)

    def _write_line(self, force: bool, gap: float) -> None:
        """A line unless one came less than ``gap`` seconds ago (``force``: a line, unless
        the last said the same)."""
        now = time.monotonic()
        if not force and now - self._last_line < gap and self._printed:
            return
        done = f"{self.n:g}/{self.total:g} {self.unit}"
        if self.total:
            done += f" ({100.0 * self.n / self.total:.0f}%)"
        postfix = self._postfix()
        text = f"{self.desc}: {done}{', ' + postfix if postfix else ''}"
        if force and text == self._printed:
            return  # The final state is on the last line already.
        self._printed = text
        self._last_line = now
        print(f"{text}; {_clock(now - self.start)} elapsed", file=self.stream, flush=True)

    def _show(self, force: bool = False) -> None:
        if self.terminal:
            self.bar.set_postfix_str(self._postfix(), refresh=False)
            self.bar.n = min(self.n, self.total) if self.total else self.n
            if force:
                self.bar.refresh()
            else:
                self.bar.update(0)  # Redraws when min_interval has passed.
        self._line()

    def update(self, n: float = 1, detail: str | None = None) -> None:
        """Adds ``n`` units of work done (and sets the details, as :meth:`detail`)."""
        if detail is not None:
            self.detail_text = detail
        self.set(self.n + n)

    def set(self, n: float) -> None:
        """Sets the units of work done to ``n``."""
        self.n = n
        if self.enabled:
            self._show()

    def phase(self, text: str) -> None:
        """Names what the work is doing now (shown until the next phase)."""
        if text != self.phase_text:
            self.phase_text = text
            if self.enabled:
                self._show(force=True)

    def detail(self, text: str) -> None:
        """Details shown after the phase (figures of the work so far)."""
        self.detail_text = text
        if self.enabled:
            self._show()

    def note(self, text: str, always: bool = False) -> None:
        """A line of its own: above the bar on a terminal, plain elsewhere where lines are
        shown; ``always``: also where nothing else is (what a user must be told)."""
        if self.terminal:
            self.bar.write(text, file=self.stream)
        elif self.lines or always:
            print(text, file=self.stream, flush=True)

    def close(self) -> None:
        """Draws the final state (a last line off a terminal) and stops (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if self.terminal:
            self._show(force=True)
        elif self.lines:
            self._line(force=True)
        self.bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["Progress", "is_terminal"]
