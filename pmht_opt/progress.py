"""A minimal text progress bar for long CLI runs (stderr; redraws in place on a terminal)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """``bar.update(k)`` after each of ``total`` units of work; ``close()`` at the end.

    On a terminal the bar redraws in place; otherwise it prints a line every ``every`` percent so logs
    stay short.
    """

    def __init__(self, total: int, label: str = "", stream: TextIO | None = None, width: int = 30) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.width = width
        self.done = 0
        self.start = time.perf_counter()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_pct = -1
        self.suffix = ""

    def update(self, n: int = 1, suffix: str = "") -> None:
        """Advance by ``n`` units; ``suffix`` is shown after the bar (e.g. the current objective)."""
        self.done = min(self.done + n, self.total)
        self.suffix = suffix
        self._draw()

    def _draw(self) -> None:
        frac = self.done / self.total
        pct = int(100 * frac)
        elapsed = time.perf_counter() - self.start
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        filled = int(self.width * frac)
        bar = "#" * filled + "-" * (self.width - filled)
        text = f"{self.label} [{bar}] {self.done}/{self.total} {elapsed:5.1f}s eta {eta:5.1f}s {self.suffix}"
        if self._tty:
            self.stream.write("\r" + text)
            self.stream.flush()
        elif pct // 10 != self._last_pct // 10 or self.done == self.total:
            self.stream.write(text + "\n")
            self.stream.flush()
        self._last_pct = pct

    def close(self) -> None:
        """Finish the line."""
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()
