"""What a backend prints, kept from the terminal and given to the caller instead.

OSQP's C code prints through Python's ``sys.stdout`` and ``sys.stderr``: the line naming a setting it
refuses (``ERROR in validate_settings: ...``) and ``Solver interrupted`` on Ctrl-C. The layer turns
what matters of that into its own exceptions, so none of it should reach a user's terminal.

Swapping ``sys.stdout`` for the duration of a call (``contextlib.redirect_stdout``) is not enough:
the swap is process-wide, so a solve on one thread would swallow what another thread prints at the
same moment, and two overlapping swaps restore each other's stream wrongly. :func:`captured` instead
puts a router in front of both streams while any thread captures: a write from a capturing thread goes
to that thread's buffer, every other write to the stream that was there before. The router is removed
when the last capture ends (unless something else has replaced the stream in between, which is then
left alone).
"""

from __future__ import annotations

import io
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO

_lock = threading.Lock()
_active = 0
_buffers: dict[int, io.StringIO] = {}


class _Router(io.TextIOBase):
    """A text stream that sends a capturing thread's writes to its buffer, others to ``target``."""

    def __init__(self, target: TextIO) -> None:
        self.target = target

    def write(self, text: str) -> int:
        buffer = _buffers.get(threading.get_ident())
        if buffer is not None:
            return buffer.write(text)
        return self.target.write(text)

    def flush(self) -> None:
        if threading.get_ident() not in _buffers:
            self.target.flush()

    def __getattr__(self, name: str) -> Any:  # encoding, isatty, fileno, ... of the real stream
        return getattr(self.target, name)


_routers: dict[str, _Router] = {}


@contextmanager
def captured() -> Iterator[io.StringIO]:
    """Within the block, what this thread prints to ``sys.stdout`` or ``sys.stderr`` goes to the
    buffer yielded; other threads print as before."""
    global _active
    buffer = io.StringIO()
    ident = threading.get_ident()
    with _lock:
        outer = _buffers.get(ident)
        if _active == 0:
            for name in ("stdout", "stderr"):
                stream = getattr(sys, name)
                if stream is not None:
                    router = _Router(stream)
                    _routers[name] = router
                    setattr(sys, name, router)
        _active += 1
        _buffers[ident] = buffer
    try:
        yield buffer
    finally:
        with _lock:
            if outer is None:
                del _buffers[ident]
            else:  # a nested capture: the outer one takes the thread's output again
                _buffers[ident] = outer
            _active -= 1
            if _active == 0:
                for name, router in _routers.items():
                    if getattr(sys, name) is router:
                        setattr(sys, name, router.target)
                _routers.clear()


def first_line(text: str) -> str:
    """The first non-empty line of ``text``, stripped (``""`` if none): what a refusal said."""
    return next((line.strip() for line in text.splitlines() if line.strip()), "")
