"""Progress of a long command on stderr, one rule for every command.

* on a terminal: a tqdm bar, redrawn in place;
* redirected (a log file, a pipe, a batch job): a plain line every
  LINE_INTERVAL_S seconds and at every LINE_STEP_PERCENT of the total, and
  one at the end (no carriage returns in the log);
* quiet (``-q``): nothing.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

LINE_INTERVAL_S = 10.0  # redirected output: at most this long between lines
LINE_STEP_PERCENT = 10.0  # ... and a line at every this much of the total
BAR_INTERVAL_S = 0.1  # a terminal's bar: redrawn at most this often (a redraw costs ~50 µs; close draws the last)


class Progress:
    """``update(done, note)`` as work proceeds, ``close()`` at the end.

    ``total``: the amount of work in ``unit`` (None: not known yet; give it to
    :meth:`update`). ``decimals``: how ``done`` and ``total`` are printed."""

    def __init__(self, desc: str, unit: str, total: float | None = None, quiet: bool = False,
                 stream: TextIO | None = None, decimals: int = 1):
        self.desc, self.unit, self.total, self.decimals = desc, unit, total, decimals
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.done, self.note = 0.0, ""
        self.started = self._last_line = time.monotonic()
        self._last_step = 0
        self._printed: tuple | None = None  # (done, note) of the last line printed
        self._bar = None
        self._last_draw = -float("inf")  # when the bar was last redrawn (time.monotonic, s)
        isatty = getattr(self.stream, "isatty", None)
        self.terminal = bool(isatty and isatty())
        if not quiet and self.terminal:
            from tqdm import tqdm

            self._bar = tqdm(total=total, unit=unit, desc=desc, file=self.stream, leave=True,
                             bar_format="{desc} {n:." + str(decimals) + "f}/{total} " + unit
                             + " |{bar}| {elapsed} {postfix}")

    def _amount(self, value: float | None) -> str:
        return "?" if value is None else f"{value:.{self.decimals}f}"

    def _line(self) -> str:
        percent = f" ({100.0 * self.done / self.total:.0f} %)" if self.total else ""
        note = f", {self.note}" if self.note else ""
        elapsed = time.monotonic() - self.started
        return (f"{self.desc} {self._amount(self.done)}/{self._amount(self.total)} {self.unit}{percent}{note}"
                f" [{elapsed:.0f} s]")

    def _print(self) -> None:
        self._printed = (self.done, self.note)
        print(self._line(), file=self.stream, flush=True)

    def update(self, done: float, note: str = "", total: float | None = None) -> None:
        """``done`` of the total so far; ``note``: a short status (e.g. the push force)."""
        if total is not None:
            self.total = total
        self.done, self.note = float(done), note
        if self.quiet:
            return
        if self._bar is not None:
            if total is not None:
                self._bar.total = total
            self._bar.n = round(self.done, self.decimals)
            now = time.monotonic()
            draw = now - self._last_draw >= BAR_INTERVAL_S
            self._bar.set_postfix_str(note, refresh=draw)
            if draw:
                self._last_draw = now
            return
        now = time.monotonic()
        step = int(100.0 * self.done / self.total // LINE_STEP_PERCENT) if self.total else 0
        if now - self._last_line >= LINE_INTERVAL_S or step > self._last_step:
            self._last_line, self._last_step = now, step
            self._print()

    def close(self) -> None:
        """End the bar, or print the last line (redirected)."""
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self._printed != (self.done, self.note):
            self._print()
        self.quiet = True  # closed: nothing more
