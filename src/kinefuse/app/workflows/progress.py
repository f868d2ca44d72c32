"""Progress of long commands on a terminal: one line on stderr, rewritten in place, shown only
when stderr is a terminal (a pipe, a log file or ``--json`` get nothing)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["TerminalProgress"]


class TerminalProgress:
    """``progress(message)`` for the workflows: shows ``kinefuse CMD: message (elapsed)``.

    ``enabled`` False (``--json``) or a ``stream`` that is not a TTY makes it silent; call
    :meth:`done` (or use it as a context manager) to clear the line at the end.
    """

    def __init__(self, command: str, *, enabled: bool = True, stream: TextIO | None = None):
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.active = bool(enabled and callable(isatty) and isatty())
        self.command = command
        self.t0 = time.monotonic()
        self._shown = False

    def __call__(self, message: str) -> None:
        if not self.active:
            return
        took = time.monotonic() - self.t0
        self.stream.write(f"\r\x1b[Kkinefuse {self.command}: {message} ({took:.0f} s)")
        self.stream.flush()
        self._shown = True

    def done(self) -> None:
        """Clear the progress line (the command's own output follows on a clean line)."""
        if self.active and self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
        self._shown = False

    def __enter__(self) -> TerminalProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.done()
